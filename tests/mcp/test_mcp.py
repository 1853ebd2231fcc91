"""`tactus mcp` driven by the MCP SDK's own client: in process (a small space), over stdio and
over streamable HTTP (real MiniLM, the shipped touch encoder, a real LanceDB store)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import anyio
import httpx
import httpx2
import pytest
from mcp import Client, StdioServerParameters
from mcp.client.streamable_http import streamable_http_client

from benchmarks.serving import free_port, wait_ok
from tactus_memory.mcp.server import READ_TOOLS, WRITE_TOOLS, build_server
from tests.helpers.mcp import fill
from tests.helpers.servers import STARTUP_S, stop_process
from tests.helpers.service import make_memory

#: a call of every read tool, with what its answer must hold
CALLS: dict[str, dict[str, Any]] = {
    "sessions": {},
    "search": {"query": "put the mug on the shelf", "k": 3},
    "last": {"query": "put the mug on the shelf", "session": "kitchen"},
    "first": {"query": "picked up the red mug", "senses": ["text"]},
    "count": {"query": "wiped the table", "session": "kitchen"},
    "before": {"anchor": "wiped the table", "window": 15.0, "senses": ["text"]},
    "after": {"anchor": "picked up the red mug", "window": 5.0},
    "timeline": {"session": "kitchen", "limit": 10},
}
#: bad arguments (schema) and library refusals: each must come back as a tool error
BAD = [
    ("search", {"query": "", "k": 3}, "query"),
    ("search", {"query": "mug", "k": 0}, "k"),
    ("search", {"query": "mug", "session": "../etc"}, "session"),
    ("search", {"query": "mug", "after": 5.0, "before": 1.0}, "after"),
    ("search", {"query": "mug", "senses": ["smell"]}, "smell"),
    ("timeline", {"session": "nowhere"}, "nowhere"),
    ("last", {}, "query"),
    ("remember", {"session": "kitchen", "text": "x"}, "remember"),  # not offered: read-only
]


def check_answers(results: dict[str, Any]) -> None:
    """What every transport must answer for CALLS over a memory made by :func:`fill`."""
    (kitchen,) = results["sessions"]["sessions"]
    assert kitchen["id"] == "kitchen" and kitchen["counts"] == {"text": 3, "touch": 1}
    top = results["search"]["hits"][0]
    assert (top["text"], top["t"], top["sense"]) == ("put the mug on the shelf", 10.0, "text")
    assert isinstance(top["score"], float) and top["id"]
    assert results["last"]["found"] and results["last"]["moment"]["t"] == 10.0
    assert results["first"]["moment"]["items"][0]["text"] == "picked up the red mug"
    assert results["count"]["count"] == 1
    assert results["count"]["occurrences"][0]["t"] == 20.0
    before = results["before"]
    assert before["anchor"]["text"] == "wiped the table"
    assert [i["text"] for i in before["items"]] == ["put the mug on the shelf"]
    after = results["after"]
    assert after["anchor"]["t"] == 1.0
    touch = [i for i in after["items"] if i["sense"] == "touch"]
    assert len(touch) == 1 and touch[0]["t"] == 2.0
    summary = touch[0]["touch"]  # a summary, never the frames
    assert summary["frames"] == 8 and 0 < summary["contact_area"] <= 1 and 0 < summary["peak"] <= 1
    assert [i["t"] for i in results["timeline"]["items"]] == [1.0, 2.0, 10.0, 20.0]


async def drive(client: Client, *, writes: bool = False) -> dict[str, Any]:
    """List the tools, call each, then the bad calls: returns the parsed answers."""
    names = [t.name for t in (await client.list_tools()).tools]
    assert names == [*READ_TOOLS, *(WRITE_TOOLS if writes else ())]
    results = {}
    for name, args in CALLS.items():
        r = await call_when_loaded(client, name, args)
        assert not r.is_error, (name, r.content)
        results[name] = json.loads(r.content[0].text)
        assert r.structured_content == results[name]
        assert "\n" not in r.content[0].text  # one compact line
    for name, args, word in BAD if not writes else BAD[:-1]:
        r = await client.call_tool(name, args)
        assert r.is_error, (name, args)
        assert word in r.content[0].text, r.content[0].text
    r = await client.call_tool("sessions", {})  # still serving after every error
    assert not r.is_error
    return results


async def call_when_loaded(client: Client, name: str, args: dict[str, Any]) -> Any:
    """A tool call, asked again while the server says its models are loading (stdio loads
    them behind ``initialize``): waits on the state, not on a time."""
    while True:
        r = await client.call_tool(name, args)
        if not (r.is_error and "loading:" in r.content[0].text):
            return r
        await anyio.sleep(0.5)


def broken(*args: Any, **kwargs: Any) -> Any:
    raise RuntimeError("disk on fire at /secret/path")


def test_tools_in_process(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem")
    fill(memory)
    schema_seen: dict[str, Any] = {}

    async def main() -> None:
        async with Client(build_server(memory, allow_writes=True)) as client:
            tools = {t.name: t for t in (await client.list_tools()).tools}
            schema_seen.update(tools["search"].input_schema["properties"])
            assert tools["search"].annotations.read_only_hint is True
            assert tools["remember"].annotations.read_only_hint is False
            assert tools["search"].description.startswith("Find remembered things")
            r = await client.call_tool("remember", {"session": "kitchen", "text": "door shut"})
            assert not r.is_error
            stored = json.loads(r.content[0].text)
            assert memory.get_item(stored["id"]).text == "door shut"
            r = await client.call_tool("remember", {"session": "kitchen", "text": "x", "meta": 3})
            assert r.is_error
            # touch answers are grasps by default (one window here: a grasp of 1); windows on ask
            r = await client.call_tool("search", {"query": "mug", "senses": ["touch"]})
            (hit,) = json.loads(r.content[0].text)["hits"]
            assert hit["grasp_windows"] == 1 and hit["sense"] == "touch"
            args = {"query": "mug", "senses": ["touch"], "windows": True}
            r = await client.call_tool("search", args)
            (hit,) = json.loads(r.content[0].text)["hits"]
            assert hit.get("grasp_windows") is None
            # an unexpected failure below the tools: a tool error naming the tool, no internals,
            # and the server goes on answering
            memory.search = broken
            r = await client.call_tool("search", {"query": "mug"})
            assert r.is_error and r.content[0].text == "Error executing tool search"
            r = await client.call_tool("sessions", {})
            assert not r.is_error and json.loads(r.content[0].text)["sessions"][0]["n"] == 5

    anyio.run(main)
    assert schema_seen["k"]["maximum"] == 50 and "description" in schema_seen["session"]


def test_tools_answer_loading_until_the_models_are_in(tmp_path) -> None:
    """``load_in_background`` (``tactus mcp`` over stdio): initialize, tools/list and the tools
    that need no model answer while the models load; a tool that embeds a text is a tool
    error saying "loading: ..."; once loaded, it answers. The load waits on a gate here."""
    import threading

    memory = make_memory(tmp_path / "mem")
    fill(memory)
    gate, entered = threading.Event(), threading.Event()
    real_search = memory.search

    def gated_search(*args: Any, **kwargs: Any) -> Any:  # the warm-up's load, held
        if threading.current_thread().name == "mcp-warm":
            entered.set()
            assert gate.wait(120)
        return real_search(*args, **kwargs)

    memory.search = gated_search

    async def main() -> None:
        server = build_server(memory, load_in_background=True)
        async with Client(server) as client:
            assert entered.wait(60)  # loading
            assert len((await client.list_tools()).tools) == len(READ_TOOLS)
            r = await client.call_tool("sessions", {})
            assert not r.is_error and json.loads(r.content[0].text)["sessions"][0]["n"] == 4
            r = await client.call_tool("timeline", {"session": "kitchen"})
            assert not r.is_error
            r = await client.call_tool("search", {"query": "mug"})
            said = r.content[0].text
            assert r.is_error and "loading: the memory is still loading" in said, said
            gate.set()
            r = await call_when_loaded(client, "search", {"query": "put the mug on the shelf"})
            assert not r.is_error
            assert json.loads(r.content[0].text)["hits"][0]["text"] == "put the mug on the shelf"

    anyio.run(main)


# ----------------------------------------------------------------------------- the real path
@pytest.fixture(scope="module")
def real_store(tmp_path_factory) -> Path:
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory

    path = tmp_path_factory.mktemp("mcp") / "memory"
    with Memory.open(str(path)) as memory:
        memory.add_sense(TactusEncoder())
        fill(memory)
    return path


def tactus(*args: str) -> list[str]:
    return [sys.executable, "-c", "from tactus_memory.cli import main; main()", *args]


def nested(levels: int) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    for _ in range(levels - 1):
        meta = {"a": meta}
    return meta


@pytest.mark.slow
def test_stdio_real_store(real_store, tmp_path) -> None:
    """Every tool over stdio; then (issue 48, defect 11) a ``remember`` whose meta nests 250
    levels gets a tool error at once, and (defect 7) ``teach`` refuses non-numbers as times,
    on a copy of the store (the writes stay out of the module's store)."""
    store = tmp_path / "store"
    shutil.copytree(real_store, store)
    cmd = tactus("mcp", "--data", str(store), "--allow-writes")
    params = StdioServerParameters(command=cmd[0], args=cmd[1:])

    async def main() -> dict[str, Any]:
        with anyio.fail_after(240):
            async with Client(params, read_timeout_seconds=120) as client:
                results = await drive(client, writes=True)
                deep = {"session": "hall", "text": "x", "meta": nested(250)}
                with anyio.fail_after(60):  # before the guard: no answer at all (liveness)
                    r = await client.call_tool("remember", deep)
                assert r.is_error and "deeper than 64" in r.content[0].text, r.content
                for times in ({"after": True}, {"before": "3"}, {"after": 1.7e18}):
                    args = {"session": "kitchen", "label": "mug", **times}
                    r = await client.call_tool("teach", args)
                    assert r.is_error, (times, r.content)
                r = await client.call_tool("sessions", {})  # still serving, nothing stored
                assert [s["id"] for s in json.loads(r.content[0].text)["sessions"]] == ["kitchen"]
                return results

    check_answers(anyio.run(main))


@pytest.mark.slow
def test_http_real_store_behind_the_token(real_store, tmp_path) -> None:
    port = free_port()
    log = tmp_path / "mcp.log"
    cmd = tactus("mcp", "--http", "--port", str(port), "--token", "s3cret", "--allow-writes")
    with log.open("wb") as fh:
        proc = subprocess.Popen(
            [*cmd, "--data", str(real_store)], stdout=fh, stderr=subprocess.STDOUT
        )
    base = f"http://127.0.0.1:{port}"
    try:
        if wait_ok(proc, base + "/live", STARTUP_S) is None:
            pytest.fail("tactus mcp --http did not start:\n" + log.read_text()[-3000:])
        body = {"jsonrpc": "2.0", "id": 1, "method": "tools/list"}
        for headers in ({}, {"Authorization": "Bearer wrong"}):
            r = httpx.post(base + "/mcp", json=body, headers=headers, timeout=60)
            assert r.status_code == 401, r.text
            assert r.headers["content-type"].startswith("application/problem+json")
            assert "bearer token" in r.json()["detail"]

        async def main() -> dict[str, Any]:
            auth = {"Authorization": "Bearer s3cret"}
            with anyio.fail_after(240):
                async with (
                    httpx2.AsyncClient(headers=auth, timeout=120) as http,
                    Client(streamable_http_client(base + "/mcp", http_client=http)) as client,
                ):
                    results = await drive(client, writes=True)
                    r = await client.call_tool(
                        "remember", {"session": "hall", "text": "the door was locked", "t": 5.0}
                    )
                    assert not r.is_error, r.content
                    r = await client.call_tool("search", {"query": "door locked", "k": 1})
                    assert json.loads(r.content[0].text)["hits"][0]["session"] == "hall"
                    return results

        check_answers(anyio.run(main))
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        stop_process(proc)


def test_cli_refuses_an_empty_token_and_a_missing_store(tmp_path) -> None:
    for args, words in [
        (("mcp", "--http", "--token", " ", "--data", str(tmp_path)), "token is empty"),
        (("mcp", "--data", str(tmp_path / "none")), "no memory at"),
    ]:
        run = subprocess.run(tactus(*args), capture_output=True, text=True, timeout=120)
        assert run.returncode == 2 and words in run.stderr, run.stderr
        assert run.stdout == ""  # stdout belongs to the protocol
