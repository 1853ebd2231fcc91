"""``tactus mcp --http``: the MCP server (``tactus_memory.mcp``) over streamable HTTP,
behind the service's bearer token.

The tools live in the library; this module only puts them on HTTP: the SDK's streamable-HTTP
app at ``/mcp``, an open ``/live`` probe, and :class:`BearerGate`, which lets through the
operator's token and the keys of the served tenant only (``auth.Gate``: one check for the API
and this endpoint), with the same 401 problem as the API routes. The keys are the store
root's (``app.key_store``), whichever tenant is served, so a store with keys is never open
here. A key of another tenant is refused like a wrong one; a key whose scope falls short
(``read`` where ``--allow-writes`` offers the ``remember`` tool) gets a 403. A request body is
read whole before the SDK sees it: larger than :data:`MAX_MCP_BODY` is a 413, JSON nested
deeper than ``limits.MAX_JSON_DEPTH`` a 400, both at once. Every ``remember`` and ``teach``
is written to the store's audit log like an HTTP write (route :data:`MCP_WRITE_ROUTE`:
``MCP remember``, ``MCP teach``). It sits in the
service because the library never imports the service, and the token check is the
service's.
"""

from __future__ import annotations

import math
from typing import Any

from mcp.server.mcpserver import MCPServer
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from tactus_memory.batches import json_depth
from tactus_memory.errors import ThrottledError
from tactus_memory.limits import MAX_JSON_DEPTH
from tactus_memory.service.auth import Gate, Principal, bearer
from tactus_memory.service.deps import BEARER_CHALLENGE, TOKEN_REFUSED
from tactus_memory.service.middleware import send_problem
from tactus_memory.service.problems import problem_body
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import allows

#: where the MCP endpoint is served (the SDK's default path)
MCP_PATH = "/mcp"
#: the open probe (no token, no data): the process answers
LIVE_PATH = "/live"
#: the largest request body the MCP endpoint reads (a note of MAX_TEXT_CHARS and a meta of
#: MAX_META_BYTES fit many times over)
MAX_MCP_BODY = 1 << 20
#: where the gate leaves the caller for the tools (``scope["state"]``, read by the audit hook)
PRINCIPAL_STATE = "tactus_principal"
#: the audit log's route for an MCP write: ``MCP remember``, ``MCP teach``
MCP_WRITE_ROUTE = "MCP {tool}"


async def read_body(receive: Receive, limit: int) -> bytes | None:
    """The whole request body, or None once it passes ``limit`` bytes."""
    chunks, size = [], 0
    while True:
        message = await receive()
        if message["type"] == "http.disconnect":
            break
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > limit:
            return None
        chunks.append(chunk)
        if not message.get("more_body", False):
            break
    return b"".join(chunks)


def replay(body: bytes, receive: Receive) -> Receive:
    """A ``receive`` that gives ``body`` once, then what ``receive`` gives (a disconnect)."""
    sent = False

    async def again() -> Any:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return again


class BearerGate:
    """ASGI: every HTTP request but :data:`LIVE_PATH` needs the operator's token or a key of
    ``tenant`` with scope ``need`` (401 / 403 problem otherwise); lifespan passes through."""

    def __init__(
        self, app: ASGIApp, gate: Gate, tenant: str, need: str, on_shutdown: Any = None
    ) -> None:
        """``on_shutdown``: called once the app has shut down (the audit log's last flush:
        uvicorn ends the process by its signal right after, so nothing after ``run`` runs)."""
        self.app = app
        self.gate = gate
        self.tenant = tenant
        self.need = need
        self.on_shutdown = on_shutdown

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "lifespan" and self.on_shutdown is not None:
            send = self._shutdown_hook(send)
        if scope["type"] == "http" and scope["path"] != LIVE_PATH:
            headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
            try:
                who = self.gate.principal(bearer(headers.get("authorization")), self.tenant)
            except ThrottledError as exc:  # a key id flooded with checks: come back later
                retry = [(b"retry-after", str(max(1, math.ceil(exc.retry_after))).encode())]
                body = problem_body(429, str(exc), instance=scope["path"])
                await send_problem(send, 429, body, retry)
                return
            if who is None or who.tenant != self.tenant:
                problem = problem_body(401, TOKEN_REFUSED, instance=scope["path"])
                challenge = [(k.lower().encode(), v.encode()) for k, v in BEARER_CHALLENGE.items()]
                await send_problem(send, 401, problem, challenge)
                return
            if who.sessions is not None:  # its tools run outside the request's context
                detail = "a key limited to sessions cannot use the MCP endpoint"
                await send_problem(send, 403, problem_body(403, detail, instance=scope["path"]))
                return
            if not allows(who.scope, self.need):
                detail = f"this key's scope is {who.scope!r}; this server needs {self.need!r}"
                await send_problem(send, 403, problem_body(403, detail, instance=scope["path"]))
                return
            scope.setdefault("state", {})[PRINCIPAL_STATE] = who
            if scope["method"] == "POST":
                body = await read_body(receive, MAX_MCP_BODY)
                if body is None:
                    detail = f"the request body is larger than {MAX_MCP_BODY} bytes"
                    await send_problem(send, 413, problem_body(413, detail, instance=scope["path"]))
                    return
                if json_depth(body) > MAX_JSON_DEPTH:
                    detail = f"the request's JSON nests deeper than {MAX_JSON_DEPTH} levels"
                    await send_problem(send, 400, problem_body(400, detail, instance=scope["path"]))
                    return
                receive = replay(body, receive)
        await self.app(scope, receive, send)

    def _shutdown_hook(self, send: Send) -> Send:
        async def sent(message: Any) -> None:
            if message["type"] == "lifespan.shutdown.complete":
                from starlette.concurrency import run_in_threadpool

                await run_in_threadpool(self.on_shutdown)
            await send(message)

        return sent


def mcp_http_app(
    server: MCPServer,
    settings: Settings,
    gate: Gate,
    tenant: str,
    need: str = "read",
    on_shutdown: Any = None,
) -> ASGIApp:
    """The streamable-HTTP app of ``server`` (serving ``tenant``'s memory) at
    :data:`MCP_PATH`, behind the token and the tenant's keys of scope ``need``
    (``on_shutdown``: called after the app's shutdown)."""

    @server.custom_route(LIVE_PATH, methods=["GET"])
    async def live(request: Request) -> JSONResponse:
        return JSONResponse({"status": "ok"})

    app = server.streamable_http_app(streamable_http_path=MCP_PATH, host=settings.host)
    return BearerGate(app, gate, tenant, need, on_shutdown)


def audit_hook(audit: Any) -> Any:
    """The ``on_write`` of :func:`~tactus_memory.mcp.server.build_server` that writes
    each write tool's call (``remember``, ``teach``) to ``audit`` (an ``AuditLog``) under the
    caller the gate let in, route ``MCP <tool>``."""

    def on_write(request: Any, tool: str, status: int, count: int) -> None:
        state = getattr(request, "scope", {}).get("state", {}) if request is not None else {}
        who = state.get(PRINCIPAL_STATE)
        if isinstance(who, Principal):
            route = MCP_WRITE_ROUTE.format(tool=tool)
            audit.record(who.key_id, who.tenant, route, status, count)

    return on_write


def run_mcp_http(memory: Any, settings: Settings, allow_writes: bool, say: Any, build: Any) -> None:
    """Serve the tools ``build(memory, allow_writes=..., on_write=...)`` makes over
    ``memory`` (one tenant's) on uvicorn at ``settings.host:port`` (tokens redacted in its
    logs), to the operator's token and the keys of that tenant (the store root's keys) with
    the scope the tools need; each ``remember`` is audited."""
    import uvicorn

    from tactus_memory.mcp.server import warm
    from tactus_memory.service.app import audit_log, key_store
    from tactus_memory.service.logs import log_config

    say("tactus mcp: loading the models (the port answers once they are loaded)")
    warm(memory)  # before the port answers: the first call is as fast as the next
    audit = audit_log(memory)
    server = build(memory, allow_writes=allow_writes, on_write=audit_hook(audit))
    need = "write" if allow_writes else "read"
    gate = Gate(settings, key_store(memory))
    app = mcp_http_app(server, settings, gate, memory.tenant, need, on_shutdown=audit.close)
    say(
        f"tactus mcp: serving {settings.data} at http://{settings.host}:{settings.port}{MCP_PATH}"
        f" (token {'required' if settings.token else 'off'})"
    )
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        log_config=log_config(),
    )
