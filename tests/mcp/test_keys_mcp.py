"""The MCP server over HTTP behind tenants' keys (issue 25): served for one tenant, on real
uvicorn; that tenant's keys (of the scope the server needs) and the operator's token get in,
another tenant's key is refused like a wrong one, a key limited to sessions is refused (403),
and the tools see the tenant's data only."""

from __future__ import annotations

import json
from typing import Any

import anyio
import httpx
import httpx2
from mcp import Client
from mcp.client.streamable_http import streamable_http_client

from benchmarks.serving import serve_app
from tactus_memory.mcp.server import build_server
from tactus_memory.memory.main import Memory
from tactus_memory.service.auth import Gate
from tactus_memory.service.mcp_http import mcp_http_app
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import KeyStore
from tests.helpers.fakes import HashingSpace

LIST = {"jsonrpc": "2.0", "id": 1, "method": "tools/list"}


def test_mcp_http_serves_one_tenant_to_its_keys(tmp_path) -> None:
    root = str(tmp_path / "mem")
    a = Memory.open(root, HashingSpace(), tenant="A")
    b = Memory.open(root, HashingSpace(), tenant="B")
    a.add("hall", "text", "the door was locked", t=1.0)
    b.add("hall", "text", "the window was open", t=1.0)
    keys = KeyStore(root)
    _, a_write = keys.create("A", "write")
    _, a_read = keys.create("A", "read")
    _, b_admin = keys.create("B", "admin")
    _, a_lab = keys.create("A", "admin", sessions="lab-")  # its tools would see every session
    settings = Settings(token="op-token")
    gate = Gate(settings, KeyStore(root))
    app = mcp_http_app(build_server(a, allow_writes=True), settings, gate, "A", "write")
    with serve_app(app) as base:
        for key, status in ((b_admin, 401), ("tk_0_x", 401), (a_read, 403), (a_lab, 403)):
            r = httpx.post(base + "/mcp", json=LIST, headers={"Authorization": f"Bearer {key}"})
            assert r.status_code == status, r.text
            assert r.headers["content-type"].startswith("application/problem+json")

        async def ask(key: str) -> list[dict[str, Any]]:
            auth = {"Authorization": f"Bearer {key}"}
            with anyio.fail_after(120):
                async with (
                    httpx2.AsyncClient(headers=auth, timeout=60) as http,
                    Client(streamable_http_client(base + "/mcp", http_client=http)) as client,
                ):
                    r = await client.call_tool("search", {"query": "window open door", "k": 5})
                    assert not r.is_error, r.content
                    return json.loads(r.content[0].text)["hits"]

        for key in (a_write, "op-token"):
            hits = anyio.run(ask, key)
            assert [h["text"] for h in hits] == ["the door was locked"]
