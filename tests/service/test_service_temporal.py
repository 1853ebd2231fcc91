"""Temporal routes over HTTP (TestClient, create_app(memory=...)): the kitchen ground truth of
tests/temporal/test_temporal.py with HashingSpace and a VectorSense touch stand-in."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.fakes import HashingSpace
from tests.helpers.kitchen import IDLE, MUG_GRASPS, NOTES, S, fill_kitchen, kitchen_memory

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def kitchen(tmp_path_factory) -> tuple[Memory, dict[str, list]]:
    path = tmp_path_factory.mktemp("temporal") / "mem"
    mem = kitchen_memory(path)
    return mem, fill_kitchen(mem)


@pytest.fixture(scope="module")
def client(kitchen):
    with TestClient(create_app(Settings(), memory=kitchen[0])) as c:
        yield c


@pytest.fixture
def fresh_client(tmp_path):
    """A store of its own, for tests that write (re-segmenting the shared one made the
    episode counts of other tests depend on the order they ran in)."""
    mem = kitchen_memory(tmp_path / "mem")
    fill_kitchen(mem)
    with TestClient(create_app(Settings(), memory=mem)) as c:
        yield c


def problem(r: Any, status: int, word: str = "") -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert word.lower() in body["detail"].lower(), body["detail"]
    return body


def test_count_last_first(client) -> None:
    r = client.get("/count", params={"q": "the mug", "session": S})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["count"] == 3 and body["capped"] is False
    assert [m["t"] for m in body["moments"]] == MUG_GRASPS
    assert all(m["senses"] == ["text", "touch"] for m in body["moments"])
    assert client.get("/count", params={"q": "giraffe savanna"}).json()["count"] == 0
    touch_only = client.get("/count", params={"q": "the mug", "sense": "touch", "merge_gap": 0})
    assert touch_only.json()["count"] == 3
    streams = client.get("/count", params={"q": "the mug", "per_stream": "true"})
    assert streams.json()["count"] == 6
    last = client.get("/last", params={"q": "the mug"}).json()["moment"]
    assert (last["t"], last["t_end"]) == (70.0, 72.5)
    first = client.get("/first", params={"q": "the mug", "after": 20}).json()["moment"]
    assert first["t"] == 40.0
    assert client.get("/last", params={"q": "giraffe savanna"}).json() == {"moment": None}
    high = client.get("/last", params={"q": "the mug", "threshold": 99}).json()
    assert high == {"moment": None}


def test_before_after(client) -> None:
    r = client.get("/before", params={"anchor": "dropped the can", "window": 25})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["anchor"]["t"] == 90.0 and body["side"] == "before"
    assert [i["t"] for i in body["items"]] == [70.0, 71.0, 72.5, 80.0, 85.0]
    params = {"anchor": "the screwdriver", "window": 20, "sense": "text", "anchor_sense": "touch"}
    r = client.get("/after", params=params)
    assert [i["text"] for i in r.json()["items"]] == [
        "picked up the screwdriver", "picked up the mug",
    ]  # fmt: skip
    none = client.get("/before", params={"anchor": "giraffe savanna"}).json()
    assert none["anchor"] is None and none["items"] == []


def test_timeline_items_and_episodes(fresh_client) -> None:
    client = fresh_client
    r = client.get(f"/sessions/{S}/timeline")
    assert r.status_code == 200, r.text
    items = r.json()["items"]
    assert len(items) == 8 + len(IDLE) + len(NOTES)
    assert [i["t_aligned"] for i in items] == sorted(i["t_aligned"] for i in items)
    r = client.get(
        f"/sessions/{S}/timeline", params={"sense": "text", "after": 10, "before": 60}
    )  # fmt: skip
    assert [i["t"] for i in r.json()["items"]] == [12.5, 30.0, 42.5, 57.5]
    r = client.get(f"/sessions/{S}/timeline", params={"sense": "touch", "episodes": "true"})
    eps = r.json()["episodes"]
    assert r.json()["items"] is None and len(eps) == 10
    assert [(e["t"], e["n"]) for e in eps if e["t"] in MUG_GRASPS] == [(t, 2) for t in MUG_GRASPS]
    r = client.post(f"/sessions/{S}/episodes", json={"max_gap": 1000.0})
    assert r.status_code == 200 and r.json()["episodes"] > 0
    # the re-segmentation is what the timeline now shows (no time gap splits any more)
    r2 = client.get(f"/sessions/{S}/timeline", params={"sense": "touch", "episodes": "true"})
    assert len(r2.json()["episodes"]) < len(eps)
    problem(client.get("/sessions/nope/timeline"), 404, "nope")
    problem(client.post("/sessions/nope/episodes"), 404, "nope")


def test_moments(client) -> None:
    r = client.get("/moments", params={"q": "the mug", "k": 3})
    assert r.status_code == 200, r.text
    moments = r.json()["moments"]
    assert sorted(m["t"] for m in moments) == MUG_GRASPS
    assert all(set(m["senses"]) == {"text", "touch"} for m in moments)
    assert all(len(m["hits"]) == 3 for m in moments)  # two touch windows and the note
    apart = client.get("/moments", params={"q": "the mug", "k": 6, "gap": 0}).json()["moments"]
    assert all(len(m["senses"]) == 1 for m in apart)


def test_clock_offsets(tmp_path) -> None:
    mem = kitchen_memory(tmp_path / "m")
    fill_kitchen(mem, notes_clock=-100.0)
    with TestClient(create_app(Settings(), memory=mem)) as c:
        assert c.get("/count", params={"q": "the mug"}).json()["count"] == 6
        r = c.put(f"/sessions/{S}/clock", json={"sense": "text", "offset": 100.0})
        assert r.status_code == 200, r.text
        assert r.json()["offsets"] == [
            {"session": S, "sense": "text", "source": "", "offset": 100.0}
        ]
        assert c.get(f"/sessions/{S}/clock").json() == r.json()
        assert c.get("/count", params={"q": "the mug"}).json()["count"] == 3
        problem(c.put(f"/sessions/{S}/clock", json={"sense": "text"}), 422, "offset")
        problem(c.put(f"/sessions/{S}/clock", json={"sense": "Bad", "offset": 1}), 422, "sense")


@pytest.mark.parametrize(
    ("path", "params", "word"),
    [
        ("/count", {}, "q"),
        ("/count", {"q": "mug", "relative": 2}, "relative"),
        ("/last", {"q": "mug", "session": "bad id!"}, "session"),
        ("/last", {"q": "mug", "after": 50, "before": 10}, "later"),
        ("/first", {"q": "mug", "after": "nan"}, "after"),
        ("/before", {"anchor": "mug", "window": -1}, "window"),
        ("/after", {}, "anchor"),
        ("/moments", {"q": "mug", "k": 0}, "k"),
        ("/moments", {"q": "mug", "gap": -1}, "gap"),
        ("/sessions/kitchen/timeline", {"limit": 0}, "limit"),
    ],
)
def test_bad_parameters_are_422(client, path, params, word) -> None:
    problem(client.get(path, params=params), 422, word)


def test_unknown_sense_is_404(client) -> None:
    problem(client.get("/count", params={"q": "mug", "sense": "smell"}), 404, "smell")
    problem(client.get(f"/sessions/{S}/timeline", params={"sense": "smell"}), 404, "smell")


def test_openapi_lists_the_temporal_routes(client) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    for p in ["/last", "/first", "/count", "/before", "/after", "/moments"]:
        assert p in paths
    assert "/sessions/{session}/timeline" in paths and "/sessions/{session}/clock" in paths


def test_search_group_moment_over_http(tmp_path) -> None:
    """GET /search?group=moment: a touch-like vector and a note at the same time form one
    moment carrying both senses; hits hold each moment's best member."""
    import numpy as np
    from fastapi.testclient import TestClient

    from tactus_memory.adapters.vectors import VectorSense
    from tactus_memory.memory.main import Memory
    from tactus_memory.service.app import create_app

    space = HashingSpace()
    memory = Memory.open(tmp_path / "m", space=space)
    memory.add_sense(VectorSense("motion", dim=space.dim))
    q = space.embed_texts(["lifting the red mug"])[0]
    memory.add("s1", "text", "lifting the red mug", t=10.0)
    memory.add("s1", "motion", q + 0.05 * np.ones_like(q), t=10.2, t_end=10.8)
    memory.add("s1", "text", "wiping the table", t=50.0)
    client = TestClient(create_app(memory=memory))
    r = client.get("/search", params={"q": "lifting the red mug", "group": "moment", "gap": 1.0})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["moments"], body
    first = body["moments"][0]
    assert set(first["senses"]) == {"text", "motion"}
    assert 9.9 < first["t"] <= 10.0 and first["t_end"] >= 10.8
    assert body["hits"][0]["id"] == first["best"]
    bad = client.get("/search", params={"q": "mug", "group": "episode"})
    assert bad.status_code == 422
    assert "group" in bad.text
