"""``tactus mcp``: the memory as MCP tools for an agent (stdio, or streamable HTTP)."""

from __future__ import annotations

from typing import Annotated

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import MemoryData, Tenant
from tactus_memory.cli.memory_cmds import _open
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail
from tactus_memory.identity import DEFAULT_TENANT

#: ``--http`` without ``--port``: beside `tactus serve`'s 8000
MCP_DEFAULT_PORT = 8001


@app.command()
def mcp(
    data: MemoryData = None,
    http: Annotated[
        bool,
        typer.Option("--http", help="Serve streamable HTTP at /mcp instead of stdio."),
    ] = False,
    host: Annotated[str | None, typer.Option(help="--http: bind address (127.0.0.1).")] = None,
    port: Annotated[
        int | None, typer.Option(help=f"--http: port (default {MCP_DEFAULT_PORT}).")
    ] = None,
    token: Annotated[
        str | None,
        typer.Option(
            help="--http: require 'Authorization: Bearer <token>', as `tactus serve` does "
            "(env TACTUS_TOKEN)."
        ),
    ] = None,
    allow_writes: Annotated[
        bool,
        typer.Option("--allow-writes", help="Offer the `remember` tool (store a note)."),
    ] = False,
    tenant: Tenant = DEFAULT_TENANT,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """Serve the memory to an agent over the Model Context Protocol.

    Tools: sessions, search, last, first, count, before, after, timeline, where, at (and
    remember, teach with --allow-writes). By default over stdio: an MCP client (an agent, a
    desktop app) starts `tactus mcp --data DIR` itself. With --http: streamable HTTP at http://HOST:PORT/mcp,
    behind the same bearer token as `tactus serve`.
    """
    try:
        from tactus_memory.mcp.server import build_server
    except ImportError as exc:
        fail(f"the MCP server needs the mcp extra: pip install 'tactus-memory[mcp]' ({exc})")
    settings = None
    if http:  # the service's settings: the same token (--token or TACTUS_TOKEN) and checks
        from pydantic import ValidationError

        from tactus_memory.settings import Settings

        given = {"host": host, "token": token, "data": data}
        overrides = {k: v for k, v in given.items() if v is not None}
        try:
            settings = Settings(**overrides, port=MCP_DEFAULT_PORT if port is None else port)
        except ValidationError as exc:
            fail("; ".join(e["msg"] for e in exc.errors()))
    from tactus_memory.settings import Settings

    # beside `tactus serve` on the same store: compaction and cleanup stay with that process
    # (or `tactus maintain`), as for a replica; this one only reads and adds a few notes
    keep_out = Settings(maintain=False).maintenance()
    memory = _open(data, space, space_path, space_dim, maintenance=keep_out, tenant=tenant)
    if settings is None:
        from tactus_memory.mcp.stdio import serve_stdio

        server = build_server(memory, allow_writes=allow_writes)
        serve_stdio(server)  # stdout is the protocol's: nothing else may print there
        return
    from tactus_memory.service.mcp_http import run_mcp_http

    settings = settings.model_copy(update={"data": memory.store.uri})
    say = lambda line: typer.echo(line, err=True)  # noqa: E731
    run_mcp_http(memory, settings, allow_writes, say, build_server)
