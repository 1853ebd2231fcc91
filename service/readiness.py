"""Store checks for ``/health`` and ``/ready``, and the read-only flag.

``store_problem(memory)`` is cheap: it reads the three tables' manifests (row counts) and
one row of the items table (vector included), so a missing or truncated data file or
manifest shows up as a reason string instead of a 500 on the next data route. It does not
scan the whole store: a damaged fragment other than the first is found by the route that
reads it (answered 503, see :func:`is_store_failure`).

``store_read_only(settings, memory)``: whether the local store directory cannot be written
(checked once at startup; object stores are assumed writable).
"""

from __future__ import annotations

import os
from typing import Any

from tactus_memory.connect import is_remote_uri, normalise_uri

#: what LanceDB's Python binding raises when a file of the store cannot be read
_LANCE_IO_MARKERS = ("LanceError(IO)", "Not found:", "No such file", "Permission denied")


def is_store_failure(exc: BaseException) -> bool:
    """True for errors that mean 'the store could not be read or written' (not a bug)."""
    if isinstance(exc, OSError):
        return True
    if isinstance(exc, RuntimeError) and str(exc).startswith("lance error"):
        return any(m in str(exc) for m in _LANCE_IO_MARKERS)
    return False


def short(exc: BaseException, limit: int = 300) -> str:
    """One line of an exception, without LanceDB's Rust source locations."""
    text = " ".join(str(exc).split())
    text = text.split(", /rustc/")[0]
    return text[:limit]


def store_problem(memory: Any) -> str | None:
    """None when the store answers (manifests + one row); else what is wrong, one line."""
    store = memory.store
    try:
        store.count()  # items manifest
        store.scan(None, ["id", "vector"], limit=1)  # one row: a data file is readable
        store.sense_rows()  # senses table (small)
        store.get_meta("space")  # meta table
    except Exception as exc:  # noqa: BLE001  (any failure is the answer: report it)
        return f"the store at {store.uri} cannot be read: {short(exc)}"
    return None


def store_read_only(uri: str) -> bool:
    """Whether a local store directory exists but cannot be written by this process."""
    if is_remote_uri(uri):
        return False
    path = normalise_uri(uri)  # the store's uri is already normalised: a local path
    return os.path.isdir(path) and not os.access(path, os.W_OK | os.X_OK)
