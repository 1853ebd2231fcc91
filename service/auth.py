"""Who is asking, for which tenant, with what right: the one gate every route passes.

:class:`Gate` turns a presented bearer value into a :class:`Principal` (key id, tenant,
scope): the operator's ``--token`` is an admin of the default tenant (or of the tenant its
``X-Tactus-Tenant`` header names); a key made by ``tactus keys create`` is what its record
says (:mod:`tactus_memory.storage.keys`); with neither a token nor any key, every request is
the anonymous admin of the default tenant (a local memory, as before keys). Once the store has
a key, a request without a valid one is refused (401).

:func:`needed_scope` says what a route needs: reads (GET, and the POSTs that only search or
render) ``read``; writes ``write``; deleting a session and registering a sense ``admin``.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass

from starlette.requests import HTTPConnection

from tactus_memory.identity import DEFAULT_TENANT, TENANT_HEADER, validate_tenant
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import KeyStore

#: key ids of the principals that are not keys
OPERATOR, ANONYMOUS = "operator", "anonymous"
#: routes (by name) whose method says write but which only read: a search by example, a
#: rendering of the posted window
READ_POSTS = frozenset({"search_like", "search_like_image", "render_touch_png"})
#: routes (by name) that only an admin key may call
ADMIN_ROUTES = frozenset({"delete_session", "add_sense"})
#: what each method needs, unless the route is named above (a WebSocket stream writes)
METHOD_SCOPE = {"GET": "read", "HEAD": "read", "DELETE": "admin", "WS": "write"}


@dataclass(frozen=True)
class Principal:
    """The caller of one request: its key id, its tenant, its key's scope and the session-id
    prefix its key is limited to (None: every session)."""

    key_id: str
    tenant: str
    scope: str
    sessions: str | None = None


def needed_scope(method: str, route_name: str | None) -> str:
    """The scope a request to the route ``route_name`` with ``method`` needs."""
    if route_name in ADMIN_ROUTES:
        return "admin"
    if route_name in READ_POSTS:
        return "read"
    return METHOD_SCOPE.get(method, "write")


def bearer(authorization: str | None) -> str | None:
    """The value of an ``Authorization: Bearer <value>`` header (None if absent or another
    scheme)."""
    if not authorization:
        return None
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return None
    return value.strip()


class Gate:
    """The principals of one store: the operator's token and the store's keys."""

    def __init__(self, settings: Settings, keys: KeyStore | None) -> None:
        self.settings = settings
        self.keys = keys

    def _operator(self, presented: str) -> bool:
        if self.settings.token is None:
            return False
        expected = self.settings.token.get_secret_value().encode()
        return hmac.compare_digest(presented.encode(), expected)  # constant time

    def principal(self, presented: str | None, tenant: str | None = None) -> Principal | None:
        """Who ``presented`` is (None: refused). ``tenant``: the operator's chosen tenant
        (the ``X-Tactus-Tenant`` header; ignored for a key, whose tenant is its own)."""
        open_store = self.settings.token is None and (self.keys is None or not self.keys.any_keys())
        if open_store:
            return Principal(ANONYMOUS, validate_tenant(tenant or DEFAULT_TENANT), "admin")
        if presented and self._operator(presented):
            return Principal(OPERATOR, validate_tenant(tenant or DEFAULT_TENANT), "admin")
        if presented and self.keys is not None:
            info = self.keys.verify(presented)
            if info is not None:
                return Principal(info.key_id, info.tenant, info.scope, info.sessions)
        return None

    def for_connection(self, conn: HTTPConnection) -> Principal | None:
        """The principal of an HTTP request or WebSocket (which may pass ``?token=``:
        browsers cannot set a WebSocket's headers)."""
        presented = bearer(conn.headers.get("authorization"))
        if conn.scope["type"] == "websocket" and presented is None:
            presented = conn.query_params.get("token")
        return self.principal(presented, conn.headers.get(TENANT_HEADER))
