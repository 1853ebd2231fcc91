"""``tactus mcp --http``: the MCP server (``tactus_memory.mcp_server``) over streamable HTTP,
behind the service's bearer token.

The tools live in the library; this module only puts them on HTTP: the SDK's streamable-HTTP
app at ``/mcp``, an open ``/live`` probe, and :class:`BearerGate`, which lets through the
operator's token and the keys of the served tenant only (``auth.Gate``: one check for the API
and this endpoint), with the same 401 problem as the API routes. A key of another tenant is
refused like a wrong one; a key whose scope falls short (``read`` where ``--allow-writes``
offers the ``remember`` tool) gets a 403. It sits in the service because the library never
imports the service, and the token check is the service's.
"""

from __future__ import annotations

from typing import Any

from mcp.server.mcpserver import MCPServer
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from tactus_memory.service.auth import Gate, bearer
from tactus_memory.service.deps import BEARER_CHALLENGE, TOKEN_REFUSED
from tactus_memory.service.middleware import send_problem
from tactus_memory.service.problems import problem_body
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import allows

#: where the MCP endpoint is served (the SDK's default path)
MCP_PATH = "/mcp"
#: the open probe (no token, no data): the process answers
LIVE_PATH = "/live"


class BearerGate:
    """ASGI: every HTTP request but :data:`LIVE_PATH` needs the operator's token or a key of
    ``tenant`` with scope ``need`` (401 / 403 problem otherwise); lifespan passes through."""

    def __init__(self, app: ASGIApp, gate: Gate, tenant: str, need: str) -> None:
        self.app = app
        self.gate = gate
        self.tenant = tenant
        self.need = need

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["path"] != LIVE_PATH:
            headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
            who = self.gate.principal(bearer(headers.get("authorization")), self.tenant)
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
        await self.app(scope, receive, send)


def mcp_http_app(
    server: MCPServer, settings: Settings, gate: Gate, tenant: str, need: str = "read"
) -> ASGIApp:
    """The streamable-HTTP app of ``server`` (serving ``tenant``'s memory) at
    :data:`MCP_PATH`, behind the token and the tenant's keys of scope ``need``."""

    @server.custom_route(LIVE_PATH, methods=["GET"])
    async def live(request: Request) -> JSONResponse:
        return JSONResponse({"status": "ok"})

    app = server.streamable_http_app(streamable_http_path=MCP_PATH, host=settings.host)
    return BearerGate(app, gate, tenant, need)


def run_mcp_http(server: MCPServer, settings: Settings, memory: Any, need: str, say: Any) -> None:
    """Serve ``server`` (over ``memory``, one tenant's) on uvicorn at ``settings.host:port``
    (tokens redacted in its logs), to the keys of that tenant with scope ``need``."""
    import uvicorn

    from tactus_memory.service.app import key_store
    from tactus_memory.service.logs import log_config

    app = mcp_http_app(server, settings, Gate(settings, key_store(memory)), memory.tenant, need)
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
