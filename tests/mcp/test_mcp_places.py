"""The MCP tools' ``where`` / ``at`` tools and ``near`` / ``frame`` / ``group`` arguments answer
as HTTP does (issue 38): the same memory served by real uvicorn and driven by the MCP SDK's own
client, the same questions asked both ways, the answers compared item by item."""

from __future__ import annotations

import json
from typing import Any

import anyio
import httpx
import numpy as np
import pytest
from mcp import Client

from benchmarks.serving import serve_app
from tactus_memory.mcp.server import READ_TOOLS, build_server
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory, window

#: a walk along x at 1 m/s: (N,) times and (N, 3) positions in frame "map"
T = np.round(np.arange(0.0, 30.0 + 1e-9, 0.1), 6)
POSITIONS = np.column_stack([T, np.zeros_like(T), np.zeros_like(T)])
NOTES = [
    (2.0, "picked up the red drill"),
    (10.0, "put the mug on the shelf"),
    (20.0, "picked up the red drill again"),
]
#: touch windows (t, seed): a hold at 3-3.6 s (two contiguous, alike windows), one at 21 s
TOUCH = [(3.0, 1), (3.3, 1), (21.0, 3)]
WINDOW_S = 0.3


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Any:
    memory = make_memory(tmp_path_factory.mktemp("places") / "mem")
    for t, note in NOTES:
        memory.add("yard", "text", note, t=t)
    for t, seed in TOUCH:
        memory.add("yard", "touch", window(seed=seed), t=t, t_end=t + WINDOW_S)
    memory.add("desk", "text", "picked up the red drill", t=5.0)  # never placed
    memory.add_poses("yard", T, POSITIONS, None, "map", "odom")
    with serve_app(create_app(Settings(), memory=memory)) as base:
        yield memory, base


def call(memory: Any, calls: list[tuple[str, dict[str, Any]]]) -> list[Any]:
    """Each (tool, arguments) through the MCP client: the parsed answer, or ``("error",
    text)`` for a tool error."""

    async def main() -> list[Any]:
        out: list[Any] = []
        async with Client(build_server(memory)) as client:
            for name, args in calls:
                r = await client.call_tool(name, args)
                text = r.content[0].text
                out.append(("error", text) if r.is_error else json.loads(text))
        return out

    return anyio.run(main)


def get(base: str, path: str, **params: Any) -> Any:
    r = httpx.get(base + path, params=params, timeout=60)
    assert r.status_code == 200, r.text
    return r.json()


def ids(items: list[dict[str, Any]]) -> list[str]:
    return [i["id"] for i in items]


def test_where_and_at_answer_as_http(served) -> None:
    memory, base = served
    where, at, near_none = call(
        memory,
        [
            ("where", {"query": "picked up the red drill", "k": 5}),
            ("at", {"x": 10.0, "y": 0.0, "z": 0.0, "r": 1.5}),
            ("where", {"query": "picked up the red drill", "near": [50.0, 0.0, 0.0, 1.0]}),
        ],
    )
    http = get(base, "/where", q="picked up the red drill", k=5)["places"]
    assert [(p["session"], p["position"], p["frame"], p["best"]) for p in where["places"]] == [
        (p["session"], [round(c, 4) for c in p["position"]], p["frame"], p["best"]) for p in http
    ]
    assert where["places"] and {p["session"] for p in where["places"]} == {"yard"}  # desk: no place
    top = where["places"][0]
    assert top["position"][0] in (2.0, 20.0) and top["frame"] == "map"
    assert top["best"] in ids(top["items"])
    assert [p["score"] for p in where["places"]] == [round(p["score"], 3) for p in http]
    http_at = get(base, "/at", x=10, y=0, z=0, r=1.5)["items"]
    assert ids(at["items"]) == ids(http_at) and [i["text"] for i in at["items"]] == [
        "put the mug on the shelf"
    ]
    assert at["position"] == [10.0, 0.0, 0.0] and at["radius"] == 1.5
    assert near_none["places"] == []
    assert get(base, "/where", q="picked up the red drill", near="50,0,0,1")["places"] == []


@pytest.mark.parametrize("group", ["auto", "window", "moment", "grasp"])
def test_search_group_and_near_answer_as_http(served, group: str) -> None:
    memory, base = served
    q = "picked up the red drill"
    everywhere, near = call(
        memory,
        [
            ("search", {"query": q, "k": 10, "group": group}),
            ("search", {"query": q, "k": 10, "group": group, "near": [2.0, 0.0, 0.0, 0.5]}),
        ],
    )
    http = get(base, "/search", q=q, k=10, group=group)
    assert ids(everywhere["hits"]) == ids(http["hits"]), (everywhere, http)
    assert [h["score"] for h in everywhere["hits"]] == [round(h["score"], 3) for h in http["hits"]]
    assert {h["session"] for h in everywhere["hits"]} == {"yard", "desk"}
    http_near = get(base, "/search", q=q, k=10, group=group, near="2,0,0,0.5")
    assert ids(near["hits"]) and ids(near["hits"]) == ids(http_near["hits"])
    assert {h["t"] for h in near["hits"]} == {2.0}  # only the note placed at x = 2
    if group == "moment":
        assert [m["best"] for m in everywhere["moments"]] == [m["best"] for m in http["moments"]]
        assert ids(everywhere["hits"]) == [m["best"] for m in everywhere["moments"]]
    else:
        assert "moments" not in everywhere
    touch = [h for h in everywhere["hits"] if h["sense"] == "touch"]
    grasp_windows = {h["grasp_windows"] for h in touch if h.get("grasp_windows")}
    if group == "window":
        assert touch and all("grasp_windows" not in h for h in touch)
    elif group in ("auto", "grasp"):
        assert grasp_windows == {1, 2}  # the two-window hold and the single one


@pytest.mark.parametrize("group", ["auto", "window", "grasp"])
def test_questions_take_group_near_and_frame_as_http(served, group: str) -> None:
    memory, base = served
    q = "picked up the red drill"
    near = [20.0, 0.0, 0.0, 1.0]
    last, count, count_near, first_frame = call(
        memory,
        [
            ("last", {"query": q, "group": group, "senses": ["text"]}),
            ("count", {"query": q, "group": group, "session": "yard", "senses": ["text"]}),
            ("count", {"query": q, "group": group, "near": near, "senses": ["text"]}),
            ("first", {"query": q, "group": group, "frame": "odom", "senses": ["text"]}),
        ],
    )
    http_last = get(base, "/last", q=q, group=group, sense="text")["moment"]
    assert last["found"] and last["moment"]["t"] == round(http_last["t"], 3)
    assert last["moment"]["best"] == http_last["best"]
    http_count = get(base, "/count", q=q, group=group, session="yard", sense="text")
    assert count["count"] == http_count["count"] == 2
    assert [m["t"] for m in count["occurrences"]] == [2.0, 20.0]
    http_near = get(base, "/count", q=q, group=group, near="20,0,0,1", sense="text")
    assert count_near["count"] == http_near["count"] == 1
    assert count_near["occurrences"][0]["t"] == 20.0
    assert first_frame == {"query": q, "found": False}  # placed in "map", not "odom"
    assert get(base, "/first", q=q, group=group, frame="odom", sense="text")["moment"] is None


def test_before_after_and_timeline_take_near_as_http(served) -> None:
    memory, base = served
    before, timeline = call(
        memory,
        [
            ("before", {"anchor": "put the mug on the shelf", "window": 9.0, "near": [6, 0, 0, 5]}),
            ("timeline", {"session": "yard", "near": [3.0, 0.0, 0.0, 1.5]}),
        ],
    )
    http = get(base, "/before", anchor="put the mug on the shelf", window=9.0, near="6,0,0,5")
    assert before["anchor"]["id"] == http["anchor"]["id"]
    assert ids(before["items"]) == ids(http["items"]) and len(before["items"]) == 3
    http_tl = get(base, "/sessions/yard/timeline", near="3,0,0,1.5")["items"]
    assert ids(timeline["items"]) == ids(http_tl)
    assert [i["t"] for i in timeline["items"]] == [2.0, 3.0, 3.3]


def test_bad_place_and_group_arguments_are_tool_errors(served) -> None:
    memory, base = served
    answers = call(
        memory,
        [
            ("search", {"query": "drill", "near": [1.0, 2.0, 3.0]}),
            ("search", {"query": "drill", "near": [1.0, 2.0, 3.0, 0.0]}),
            ("search", {"query": "drill", "group": "grasp", "windows": True}),
            ("search", {"query": "drill", "group": "cluster"}),
            ("count", {"query": "drill", "group": "moment"}),
            ("at", {"x": 1.0, "y": 0.0, "z": 0.0, "r": -1.0}),
            ("where", {"query": "drill", "session": "nowhere"}),
            ("at", {"x": 1.0, "y": 0.0, "z": 0.0, "r": 1.0, "session": "nowhere"}),
        ],
    )
    said = [a[1] if a[0] == "error" else None for a in answers]
    assert all(said), answers
    assert "near" in said[0] and "radius" in said[1]
    assert "windows: true" in said[2] and "group" in said[3] and "group" in said[4]
    assert "r" in said[5] and "no session 'nowhere'" in said[6] and "nowhere" in said[7]
    # HTTP refuses the same radius
    r = httpx.get(base + "/search", params={"q": "drill", "near": "1,2,3,0"}, timeout=60)
    assert r.status_code == 422 and "radius" in r.text


def test_the_place_tools_are_listed_read_only_with_their_arguments(served) -> None:
    memory, _ = served

    async def main() -> dict[str, Any]:
        async with Client(build_server(memory)) as client:
            return {t.name: t for t in (await client.list_tools()).tools}

    tools = anyio.run(main)
    assert {"where", "at"} <= set(tools) and {"where", "at"} <= set(READ_TOOLS)
    for name in ("where", "at"):
        assert tools[name].annotations.read_only_hint is True
    for name in ("search", "last", "first", "count", "before", "after", "timeline", "where"):
        props = tools[name].input_schema["properties"]
        assert {"near", "frame"} <= set(props), (name, sorted(props))
    for name in ("search", "last", "first", "count"):
        assert "group" in tools[name].input_schema["properties"], name
    assert set(tools["at"].input_schema["required"]) == {"x", "y", "z", "r"}
