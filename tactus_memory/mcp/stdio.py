"""``tactus mcp`` over stdio: the SDK's stdio transport with a depth guard in front of it.

The SDK parses each stdin line with pydantic-core, whose JSON parser stops at its recursion
limit; the SDK then answers nothing at all, and the agent waits forever (issue 48: a
``remember`` whose meta nests 250 levels got no reply in 90 s). :class:`DepthGuard` reads the
lines first: one nesting deeper than ``limits.MAX_JSON_DEPTH`` (the limit the HTTP door
answers 400 at, :mod:`tactus_memory.service.mcp_http`) is answered at once, a tool error for
a ``tools/call`` (so the agent reads why) and a JSON-RPC error for anything else, and never
reaches the parser; the rest go to the SDK unchanged.
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from typing import Any

import anyio
import mcp_types as types
from mcp.server.mcpserver import MCPServer
from mcp.server.stdio import stdio_server
from mcp.shared.message import SessionMessage

from tactus_memory.batches import json_depth
from tactus_memory.limits import MAX_JSON_DEPTH, MAX_META_DEPTH


def too_deep(line: str) -> str | None:
    """Why ``line`` is refused (it nests deeper than MAX_JSON_DEPTH), or None."""
    depth = json_depth(line.encode("utf-8", "replace"))
    if depth <= MAX_JSON_DEPTH:
        return None
    return (
        f"the request's JSON nests {depth} levels, deeper than {MAX_JSON_DEPTH} (a meta may "
        f"nest at most {MAX_META_DEPTH}); nothing was stored"
    )


def refusal(line: str, why: str) -> types.JSONRPCMessage:
    """The answer to a refused request line: a tool error for ``tools/call``, else an
    invalid-request error; its id is the request's when Python's parser can read it."""
    msg_id: Any = None
    method = None
    try:
        obj = json.loads(line)
        if isinstance(obj, dict):
            msg_id, method = obj.get("id"), obj.get("method")
    except (ValueError, RecursionError):
        pass
    if not isinstance(msg_id, (int, str)) or isinstance(msg_id, bool):
        msg_id = None
    if method == "tools/call" and msg_id is not None:
        result = types.CallToolResult(
            content=[types.TextContent(type="text", text=why)], is_error=True
        )
        body = result.model_dump(by_alias=True, exclude_none=True, mode="json")
        return types.JSONRPCResponse(jsonrpc="2.0", id=msg_id, result=body)
    error = types.ErrorData(code=types.INVALID_REQUEST, message=why)
    return types.JSONRPCError(jsonrpc="2.0", id=msg_id, error=error)


class DepthGuard:
    """stdin's lines for the SDK's transport, the too-deep ones answered on ``reply``."""

    def __init__(self, lines: Any) -> None:
        self.lines = lines
        self.reply: Any = None  # the transport's write stream, set once it is open
        self.ready = anyio.Event()

    def __aiter__(self) -> AsyncIterator[str]:
        return self._lines()

    async def _lines(self) -> AsyncIterator[str]:
        async for line in self.lines:
            why = too_deep(line)
            if why is None:
                yield line
                continue
            await self.ready.wait()
            await self.reply.send(SessionMessage(refusal(line, why)))


async def run_stdio(server: MCPServer) -> None:
    """Serve ``server`` over stdin/stdout, as ``server.run("stdio")`` does, behind the
    :class:`DepthGuard`."""
    stdin = anyio.wrap_file(open(0, encoding="utf-8", errors="replace", closefd=False))  # noqa: SIM115
    guard = DepthGuard(stdin)
    lowlevel = server._lowlevel_server  # what MCPServer.run_stdio_async runs
    async with stdio_server(stdin=guard) as (read_stream, write_stream):  # type: ignore[arg-type]
        guard.reply = write_stream
        guard.ready.set()
        await lowlevel.run(read_stream, write_stream, lowlevel.create_initialization_options())


def serve_stdio(server: MCPServer) -> None:
    """Block serving ``server`` over stdio (stdout is the protocol's: nothing else prints)."""
    anyio.run(run_stdio, server)
