"""Issue 36, defect 1 and its neighbours on the real path: ``tactus mcp --http`` in a
subprocess (uvicorn on 127.0.0.1, the real MiniLM space, a real LanceDB store with three
tenants) behind the store root's keys. The gate matrix (no token, a wrong one, the operator's
token, each tenant's keys, a key limited to sessions, a read key) for a server of tenant A
with and without ``--token`` and for a server of the default tenant; a ``remember`` through
the MCP SDK's client lands in the served tenant and in the audit log; ``t: true`` is refused;
a meta nested 250 levels is a 400 at once."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import anyio
import httpx
import httpx2
import pytest
from mcp import Client
from mcp.client.streamable_http import streamable_http_client

from benchmarks.serving import free_port, wait_ok
from tactus_memory.storage.audit import AuditLog
from tactus_memory.storage.keys import KeyStore
from tests.helpers.servers import STARTUP_S, stop_process

pytestmark = pytest.mark.slow

TACTUS = [sys.executable, "-c", "from tactus_memory.cli import main; main()"]
INIT = {
    "jsonrpc": "2.0",
    "id": 1,
    "method": "initialize",
    "params": {
        "protocolVersion": "2025-06-18",
        "capabilities": {},
        "clientInfo": {"name": "matrix", "version": "0"},
    },
}
ACCEPT = {"Accept": "application/json, text/event-stream"}


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> dict[str, Any]:
    """Tenants default, A and B (a note each) and their keys."""
    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace

    root = tmp_path_factory.mktemp("mcp-tenants") / "memory"
    space = MiniLMSpace()
    for tenant, note in (("default", "the oven was hot"), ("A", "the door was locked"),
                         ("B", "the window was open")):  # fmt: skip
        with Memory.open(str(root), space, tenant=tenant) as memory:
            memory.add("hall", "text", note, t=1.0)
    keys = KeyStore(str(root))
    made = {
        "A_write": keys.create("A", "write"),
        "A_read": keys.create("A", "read"),
        "A_prefix": keys.create("A", "write", sessions="lab-"),
        "B_write": keys.create("B", "write"),
        "B_admin": keys.create("B", "admin"),
        "default_write": keys.create("default", "write"),
        "default_prefix": keys.create("default", "admin", sessions="lab-"),
    }
    return {"root": root, "keys": {name: key for name, (_, key) in made.items()},
            "ids": {name: key_id for name, (key_id, _) in made.items()}}  # fmt: skip


@contextmanager
def mcp_server(root: Path, log: Path, *extra: str) -> Iterator[str]:
    port = free_port()
    cmd = [*TACTUS, "mcp", "--http", "--port", str(port), "--data", str(root), *extra]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("TACTUS_TOKEN", None)
    with log.open("ab") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env)
    base = f"http://127.0.0.1:{port}"
    try:
        if wait_ok(proc, base + "/live", STARTUP_S) is None:
            pytest.fail(f"{' '.join(extra)}: tactus mcp --http did not start:\n"
                        + log.read_text()[-3000:])  # fmt: skip
        yield base
    finally:
        stop_process(proc)


def status_of(base: str, key: str | None) -> int:
    headers = dict(ACCEPT)
    if key is not None:
        headers["Authorization"] = f"Bearer {key}"
    r = httpx.post(base + "/mcp", json=INIT, headers=headers, timeout=60)
    if r.status_code != 200:
        assert r.headers["content-type"].startswith("application/problem+json"), r.text
    return r.status_code


def matrix(base: str, keys: dict[str, str], expected: dict[str | None, int]) -> None:
    seen = {who: status_of(base, keys.get(who, who)) for who in expected}
    assert seen == expected


async def remember(base: str, key: str, args: dict[str, Any], tool: str = "remember") -> Any:
    auth = {"Authorization": f"Bearer {key}"}
    with anyio.fail_after(120):
        async with (
            httpx2.AsyncClient(headers=auth, timeout=60) as http,
            Client(streamable_http_client(base + "/mcp", http_client=http)) as client,
        ):
            return await client.call_tool(tool, args)


def nested(levels: int) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    inner = meta
    for _ in range(levels - 1):
        inner["a"] = {}
        inner = inner["a"]
    return meta


def test_tenant_server_without_token_is_closed_to_all_but_its_keys(store, tmp_path) -> None:
    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace

    root, keys = store["root"], store["keys"]
    with mcp_server(root, tmp_path / "a.log", "--tenant", "A", "--allow-writes") as base:
        matrix(
            base,
            keys,
            {
                None: 401,  # the open door of issue 36
                "tk_000000000000_wrong": 401,
                "op-token": 401,  # no operator token configured: not a key either
                "A_write": 200,
                "A_read": 403,  # remember needs write
                "A_prefix": 403,  # limited to sessions: its tools would see every session
                "B_write": 401,
                "B_admin": 401,
                "default_write": 401,
                "default_prefix": 401,
            },
        )
        note = {"session": "hall", "text": "mcp note A", "t": 7.0}
        r = anyio.run(remember, base, keys["A_write"], note)
        assert not r.is_error, r.content
        note_id = json.loads(r.content[0].text)["id"]
        # booleans are not numbers: refused, nothing stored
        r = anyio.run(remember, base, keys["A_write"], {"session": "hall", "text": "x", "t": True})
        assert r.is_error and "valid number" in r.content[0].text, r.content
        # a meta nested 250 levels: a 400 at once (the SDK alone never answered)
        args = {"session": "hall", "text": "x", "meta": nested(250)}
        deep = {"jsonrpc": "2.0", "id": 2, "method": "tools/call",
                "params": {"name": "remember", "arguments": args}}  # fmt: skip
        auth = {**ACCEPT, "Authorization": f"Bearer {keys['A_write']}"}
        r = httpx.post(base + "/mcp", json=deep, timeout=30, headers=auth)
        assert r.status_code == 400 and "nests deeper" in r.json()["detail"], r.text
        # issue 48, defect 6: teach is audited like remember (refused here: no touch windows)
        teach = {"session": "hall", "label": "drill"}
        r = anyio.run(remember, base, keys["A_write"], teach, "teach")
        assert r.is_error, r.content
    space = MiniLMSpace()
    with Memory.open(str(root), space, tenant="A") as a:
        assert a.get_item(note_id).text == "mcp note A"
        assert [i.text for i in a.timeline("hall")] == ["the door was locked", "mcp note A"]
    with Memory.open(str(root), space, tenant="B") as b:
        assert [i.text for i in b.timeline("hall")] == ["the window was open"]
    entries = [e for e in AuditLog(str(root)).entries() if e.route == "MCP remember"]
    stored = [(e.key_id, e.tenant, e.status, e.count) for e in entries]
    assert (store["ids"]["A_write"], "A", 201, 1) in stored, stored
    taught = [(e.key_id, e.tenant, e.status) for e in AuditLog(str(root)).entries()
              if e.route == "MCP teach"]  # fmt: skip
    assert (store["ids"]["A_write"], "A", 422) in taught, taught


def test_tenant_server_with_token(store, tmp_path) -> None:
    keys = store["keys"]
    extra = ("--tenant", "A", "--allow-writes", "--token", "op-token")
    with mcp_server(store["root"], tmp_path / "b.log", *extra) as base:
        matrix(
            base,
            keys,
            {
                None: 401,
                "op-token": 200,
                "A_write": 200,  # issue 36: every key of A got 401 here
                "A_read": 403,
                "A_prefix": 403,
                "B_write": 401,
                "default_write": 401,
            },
        )


def test_default_tenant_server_read_only(store, tmp_path) -> None:
    keys = store["keys"]
    with mcp_server(store["root"], tmp_path / "c.log") as base:
        matrix(
            base,
            keys,
            {
                None: 401,
                "op-token": 401,
                "default_write": 200,
                "default_prefix": 403,
                "A_write": 401,
                "A_read": 401,
                "B_admin": 401,
            },
        )
