"""Issue 48 on the MCP tools, driven by the MCP SDK's own client (in process, a small space):
the time rule on every tool that takes a time (each edge value refused as a tool error, or
stored, and then every read tool answers), ``teach`` as strict about numbers as ``remember``
(defect 7) and audited like it (defect 6), labels with format characters refused (defect 9).
Over stdio (defect 11) see tests/mcp/test_mcp.py::test_stdio_real_store."""

from __future__ import annotations

import json
import math
from typing import Any

import anyio
import pytest
from mcp import Client

from tactus_memory.mcp.server import build_server
from tactus_memory.mcp.stdio import refusal, too_deep
from tests.helpers.mcp import fill
from tests.helpers.service import make_memory

#: the issue's edge values (MCP arguments are JSON: inf and nan travel as floats here)
EDGES: list[Any] = [0, -0.0, 5e-324, 1e9, 1.7e18, 1e308, math.inf, -math.inf, math.nan]
EDGES += [True, False, "3"]
KEPT = {0, 5e-324, 1e9}
#: a liveness bound per read tool call (the freeze never answered); not a speed target
READ_LIVENESS_S = 30.0

#: every tool argument that is a time: (tool, the other arguments, the time's name)
TIME_ARGS: list[tuple[str, dict[str, Any], str]] = [
    ("remember", {"session": "kitchen", "text": "a note"}, "t"),
    ("teach", {"session": "kitchen", "label": "mug"}, "after"),
    ("teach", {"session": "kitchen", "label": "mug"}, "before"),
    # after and before of every question are one type (mcp/args.py: AfterArg, BeforeArg)
    ("search", {"query": "the mug"}, "after"),
    ("last", {"query": "the mug"}, "before"),
    ("first", {"query": "the mug"}, "after"),
    ("count", {"query": "the mug"}, "before"),
    ("timeline", {"session": "kitchen"}, "after"),
    ("where", {"query": "the mug"}, "after"),
    ("at", {"x": 0, "y": 0, "z": 0, "r": 1}, "before"),
]
#: the reads that must answer after anything was stored
READS: list[tuple[str, dict[str, Any]]] = [
    ("search", {"query": "holding a mug", "k": 5}),
    ("search", {"query": "holding a mug", "k": 5, "group": "grasp"}),
    ("last", {"query": "holding a mug"}),
    ("count", {"query": "holding a mug"}),
    ("after", {"anchor": "picked up the red mug"}),
    ("timeline", {"session": "kitchen"}),
    ("sessions", {}),
]


def test_every_time_argument_refused_or_stored_and_reads_answer(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem")
    fill(memory)
    server = build_server(memory, allow_writes=True)
    seen: list[tuple[str, str, Any, bool]] = []

    async def main() -> None:
        async with Client(server) as client:
            schemas = {t.name: t.input_schema for t in (await client.list_tools()).tools}
            timed = set()  # the schema an agent sees states the rule on every time
            for tool, schema in schemas.items():
                for name, prop in schema["properties"].items():
                    if name in ("t", "t_end", "after", "before"):
                        options = prop.get("anyOf", [prop])
                        numbers = [o for o in options if o.get("type") == "number"]
                        assert numbers and numbers[0]["maximum"] == 1e10, (tool, name, prop)
                        timed.add(tool)
            assert timed == {tool for tool, _, _ in TIME_ARGS}  # every such tool is sent
            for v in EDGES:
                stored = False
                for tool, args, name in TIME_ARGS:
                    r = await client.call_tool(tool, {**args, name: v})
                    kept = not isinstance(v, (bool, str)) and v in KEPT
                    seen.append((tool, name, v, r.is_error))
                    if isinstance(v, float) and not math.isfinite(v):
                        pass  # JSON has no inf/nan: the SDK's client sends null (no time)
                    elif not kept:
                        assert r.is_error, (tool, name, v, r.content)
                        if isinstance(v, float) and abs(v) > 1e17:
                            assert "seconds, not nanoseconds?" in r.content[0].text
                    elif tool != "teach":  # a teach span may hold no window: its own error
                        assert not r.is_error, (tool, name, v, r.content)
                    stored |= not r.is_error and tool in ("remember", "teach")
                if stored:  # whatever this value stored, every read answers
                    for read, read_args in READS:
                        with anyio.fail_after(READ_LIVENESS_S):
                            got = await client.call_tool(read, read_args)
                        assert not got.is_error, (read, got.content)

    anyio.run(main)
    assert len(seen) == len(TIME_ARGS) * len(EDGES)
    assert all(abs(i.t) <= 1e10 and abs(i.t_end) <= 1e10 for i in memory.timeline("kitchen"))


def test_teach_refuses_non_numbers_and_format_characters_and_is_audited(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem")
    fill(memory)  # a touch window at 2.0-2.3 in kitchen
    writes: list[tuple[str, int, int]] = []
    server = build_server(
        memory, allow_writes=True, on_write=lambda _req, tool, st, n: writes.append((tool, st, n))
    )

    async def main() -> None:
        async with Client(server) as client:
            for args in ({"after": True}, {"before": "3"}, {"after": False}):
                r = await client.call_tool("teach", {"session": "kitchen", "label": "mug", **args})
                assert r.is_error and "valid number" in r.content[0].text, (args, r.content)
            for label in ("dri\u202ell\u200b", "mug\ufeff", "\u2066cup\u2069"):
                r = await client.call_tool("teach", {"session": "kitchen", "label": label})
                assert r.is_error and "format characters" in r.content[0].text, r.content
            r = await client.call_tool(
                "teach", {"session": "kitchen", "label": "mug", "after": 1.9, "before": 2.4}
            )
            assert not r.is_error, r.content
            assert json.loads(r.content[0].text)["windows"] == 1

    anyio.run(main)
    assert memory.taught() and [t.label for t in memory.taught()] == ["mug"]
    # every teach that reached the tool is audited (the SDK refuses bad types before it)
    assert writes == [("teach", 422, 0)] * 3 + [("teach", 201, 1)], writes


@pytest.mark.parametrize("levels", [65, 250, 100_000])
def test_a_too_deep_stdio_line_is_answered_at_once(levels: int) -> None:
    """The stdio guard's answer to a line nesting deeper than MAX_JSON_DEPTH: a tool error
    with the request's id for tools/call (an id of null when even Python cannot parse it)."""
    meta = "[" * levels + "]" * levels
    line = (
        '{"jsonrpc": "2.0", "id": 7, "method": "tools/call", "params": {"name": "remember", '
        f'"arguments": {{"session": "s", "text": "x", "meta": {meta}}}}}}}'
    )
    why = too_deep(line)
    assert why is not None and "deeper than 64" in why
    answer = refusal(line, why).model_dump(by_alias=True, exclude_none=True)
    if levels < 500:
        assert answer["id"] == 7 and answer["result"]["isError"] is True
        assert "nothing was stored" in answer["result"]["content"][0]["text"]
    else:  # beyond Python's recursion limit: a JSON-RPC error the client still reads
        assert answer["error"]["message"] == why
    assert too_deep('{"jsonrpc": "2.0", "id": 1, "method": "tools/list"}') is None
