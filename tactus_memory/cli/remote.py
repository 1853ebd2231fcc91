"""``--url``: the memory commands ask a running ``tactus serve`` over HTTP instead of opening
the store, so no model is loaded in the shell (opening MiniLM takes seconds on every call).

Plain httpx GETs on the service's own routes (``/search``, ``/last``, ``/first``, ``/count``,
``/sessions``, ``/sessions/{id}/timeline``); the answers are validated into the library's
result models, so both modes print alike. A problem answer (4xx/5xx) is one line on stderr
and exit status 2, as a local error is.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
from urllib.parse import quote

from tactus_memory.cli.space_opts import fail
from tactus_memory.identity import DEFAULT_TENANT, auth_headers

#: seconds one request may take (a search answers in milliseconds once the server is ready)
TIMEOUT_S = 60.0


def get_json(
    url: str,
    path: str,
    params: Mapping[str, Any],
    token: str | None = None,
    tenant: str = DEFAULT_TENANT,
) -> Any:
    """GET ``url + path`` with ``params`` (None dropped; lists repeat the key) as ``tenant``
    (the operator's tenant header); the JSON answer, or a one-line error and exit 2."""
    import httpx

    query = {k: v for k, v in params.items() if v is not None and v != []}
    headers = auth_headers(token, None if tenant == DEFAULT_TENANT else tenant)
    target = url.rstrip("/") + path
    try:
        response = httpx.get(target, params=query, headers=headers, timeout=TIMEOUT_S)
    except httpx.HTTPError as exc:
        fail(f"cannot reach the server at {url} ({exc}): is `tactus serve` running there?")
    if response.status_code >= 400:
        try:
            detail = response.json().get("detail", response.text)
        except ValueError:
            detail = response.text[:300]
        fail(f"{response.status_code} from {target}: {detail}")
    return response.json()


def session_path(session: str, tail: str = "") -> str:
    """``/sessions/{session}{tail}`` with the id quoted for a URL path."""
    return f"/sessions/{quote(session, safe='')}{tail}"
