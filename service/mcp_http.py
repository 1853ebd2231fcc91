"""``tactus mcp --http``: the MCP server (``tactus_memory.mcp_server``) over streamable HTTP,
behind the service's bearer token.

The tools live in the library; this module only puts them on HTTP: the SDK's streamable-HTTP
app at ``/mcp``, an open ``/live`` probe, and :class:`BearerGate`, which refuses a request
without the configured token with the same 401 problem as the API routes (``deps.token_ok``,
``deps.bearer``: one check for both). It sits in the service because the library never
imports the service, and the token check is the service's.
"""

from __future__ import annotations

from typing import Any

from mcp.server.mcpserver import MCPServer
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from tactus_memory.service.deps import BEARER_CHALLENGE, TOKEN_REFUSED, bearer, token_ok
from tactus_memory.service.middleware import send_problem
from tactus_memory.service.problems import problem_body
from tactus_memory.service.settings import Settings

#: where the MCP endpoint is served (the SDK's default path)
MCP_PATH = "/mcp"
#: the open probe (no token, no data): the process answers
LIVE_PATH = "/live"


class BearerGate:
    """ASGI: every HTTP request but :data:`LIVE_PATH` needs ``Authorization: Bearer <token>``
    when ``settings.token`` is set (401 problem otherwise); lifespan passes through."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.settings = settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["path"] != LIVE_PATH:
            headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
            if not token_ok(self.settings, bearer(headers.get("authorization"))):
                problem = problem_body(401, TOKEN_REFUSED, instance=scope["path"])
                challenge = [(k.lower().encode(), v.encode()) for k, v in BEARER_CHALLENGE.items()]
                await send_problem(send, 401, problem, challenge)
                return
        await self.app(scope, receive, send)


def mcp_http_app(server: MCPServer, settings: Settings) -> ASGIApp:
    """The streamable-HTTP app of ``server`` at :data:`MCP_PATH`, behind the token."""

    @server.custom_route(LIVE_PATH, methods=["GET"])
    async def live(request: Request) -> JSONResponse:
        return JSONResponse({"status": "ok"})

    app = server.streamable_http_app(streamable_http_path=MCP_PATH, host=settings.host)
    return BearerGate(app, settings)


def run_mcp_http(server: MCPServer, settings: Settings, say: Any) -> None:
    """Serve ``server`` on uvicorn at ``settings.host:port`` (tokens redacted in its logs)."""
    import uvicorn

    from tactus_memory.service.logs import log_config

    app = mcp_http_app(server, settings)
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
