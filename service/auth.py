"""Who is asking, for which tenant, with what right: the one gate every route passes.

:class:`Gate` turns a presented bearer value into a :class:`Principal` (key id, tenant,
scope): the operator's ``--token`` is an admin of the default tenant (or of the tenant its
``X-Tactus-Tenant`` header names); a key made by ``tactus keys create`` is what its record
says (:mod:`tactus_memory.storage.keys`); with neither a token nor any key, every request is
the anonymous admin of the default tenant (a local memory, as before keys). Once the store has
a key, a request without a valid one is refused (401).

:func:`needs` is how a route says what it needs, where the route is declared
(``dependencies=[needs("read")]``, ``deps.Read``/``Write``/``Admin``/``Open``): reads (GET, and
the POSTs that only search or render) ``read``; writes ``write``; deleting and registering a
sense ``admin``; the health probes, the static page and the API docs ``open``.
:func:`declared_scope` reads it back from the route (``deps.authorize``, and the test that
fails when a route declares none).
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Any

from fastapi import Depends
from fastapi.params import Depends as DependsParam
from starlette.requests import HTTPConnection

from tactus_memory.identity import DEFAULT_TENANT, TENANT_HEADER, validate_tenant
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import KeyStore, check_scope

#: key ids of the principals that are not keys
OPERATOR, ANONYMOUS = "operator", "anonymous"
#: the scope of a route anyone may call, with no key (a health probe, the page, the API docs)
OPEN = "open"


@dataclass(frozen=True)
class Principal:
    """The caller of one request: its key id, its tenant, its key's scope and the session-id
    prefix its key is limited to (None: every session)."""

    key_id: str
    tenant: str
    scope: str
    sessions: str | None = None


@dataclass(frozen=True)
class RouteScope:
    """The scope a route declares, as one of its dependencies (:func:`needs`). Calling it
    checks nothing: ``deps.authorize`` (which every route but the open ones runs) reads the
    declared scope from the route and refuses a key whose scope falls short."""

    scope: str

    def __call__(self) -> str:
        return self.scope


def needs(scope: str) -> Any:
    """The dependency by which a route declares the scope it needs (``read``, ``write``,
    ``admin``, or :data:`OPEN`)."""
    if scope != OPEN:
        check_scope(scope)
    return Depends(RouteScope(scope))


def declared_scope(route: object) -> str | None:
    """The scope ``route`` declares (None: it declares none). The app's routes carry the
    dependencies of their router and of their own decorator."""
    for dep in getattr(route, "dependencies", None) or ():
        if isinstance(dep, DependsParam) and isinstance(dep.dependency, RouteScope):
            return dep.dependency.scope
    return None


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
