"""Logging for ``tactus serve``: secrets never reach a log line.

uvicorn's access log prints the request line with its query string, and its WebSocket lines
print the path with the query: a token passed as ``?token=`` would be written verbatim.
:class:`RedactSecrets` (a ``logging.Filter`` on every uvicorn handler, see
:func:`log_config`) replaces the value of ``token``/``access_token`` query parameters and of
``Bearer`` credentials with ``***`` before a record is formatted. A query parameter's name is
compared once percent-decoded, as the server reads it (``?tok%65n=`` is ``?token=``), and
a value that is an API key (``tk_...``, decoded) is redacted whatever its parameter's name.
"""

from __future__ import annotations

import copy
import logging
import re
from typing import Any
from urllib.parse import unquote_plus

REDACTED = "***"
#: ``token=...`` / ``access_token=...`` query values, and ``Bearer <credential>``
SECRET_RE = re.compile(r"(?i)((?:[?&;]|\b)(?:access_)?token=)[^&\s\"';]*|(bearer\s+)[^\s\"',]+")


#: the query parameters whose value is a secret (names compared percent-decoded, lowercase)
SECRET_PARAMS = frozenset({"token", "access_token"})
#: a query string in a log line: after ``?``, up to a space or a quote
QUERY_RE = re.compile(r"\?([^\s\"'#]*)")
#: an API key's start (storage.keys.KEY_PREFIX), decoded
KEY_START = "tk_"


def _redact_param(part: str) -> str:
    name, eq, value = part.partition("=")
    if not eq:
        return part
    secret = unquote_plus(name).strip().lower() in SECRET_PARAMS
    if secret or unquote_plus(value).strip().startswith(KEY_START):
        return f"{name}={REDACTED}"
    return part


def _redact_query(m: re.Match[str]) -> str:
    parts = re.split(r"([&;])", m.group(1))
    return "?" + "".join(p if p in "&;" else _redact_param(p) for p in parts)


def redact(text: str) -> str:
    text = QUERY_RE.sub(_redact_query, text)
    return SECRET_RE.sub(lambda m: (m.group(1) or m.group(2)) + REDACTED, text)


def _clean(value: Any) -> Any:
    return redact(value) if isinstance(value, str) else value


class RedactSecrets(logging.Filter):
    """Redacts tokens in a record's message and string arguments (never drops a record)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(_clean(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: _clean(v) for k, v in record.args.items()}
        return True


#: the logger whose lines ``tactus serve`` prints at its log level (beside uvicorn's): each
#: maintenance pass, with who ran it (``storage.store.set_maintainer``) and its pid
MAINTENANCE_LOGGER = "tactus_memory.storage.store"


def log_config(level: str | None = None) -> dict[str, Any]:
    """uvicorn's default logging config with :class:`RedactSecrets` on every handler; with
    ``level`` (the server's), the store's lines (maintenance passes) at that level too."""
    from uvicorn.config import LOGGING_CONFIG

    config = copy.deepcopy(LOGGING_CONFIG)
    config.setdefault("filters", {})["redact_secrets"] = {"()": f"{__name__}.RedactSecrets"}
    for handler in config["handlers"].values():
        handler.setdefault("filters", []).append("redact_secrets")
    if level is not None:
        config["loggers"][MAINTENANCE_LOGGER] = {
            "handlers": ["default"],
            "level": level.upper(),
            "propagate": False,
        }
    return config
