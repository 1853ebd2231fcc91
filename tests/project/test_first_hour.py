"""Issue 26's smaller promises, fast (HashingSpace, a stand-in touch sense, TestClient):
errors a newcomer meets say the shape in one line, reads never write, the match bar is on
every hit, an unknown session is a 404 everywhere, and the server answers while it starts."""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import InvalidInputError
from tactus_memory.matching import GRASP_MATCH_Z, MATCH_Z, RELATIVE_KEEP
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import assert_problem, make_memory, window


@pytest.fixture
def client(tmp_path: Path):
    memory = make_memory(tmp_path / "m")
    with TestClient(create_app(Settings(), memory=memory)) as c:
        yield c


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_a_single_frame_as_json_is_one_line_naming_the_shape(client) -> None:
    frame = window(1)[0].tolist()  # (32, 32): one frame, not a window
    r = client.post("/sessions/s/touch", json={"frames": frame, "t": 1.0})
    body = assert_problem(r, 422, "must have shape (K, H, W)", "32x32 on the glove", "got (32, 32)")
    assert "more" not in body["detail"] and len(body["detail"]) < 200, body["detail"]
    r = client.post("/search/like", json={"sense": "touch", "frames": frame})
    assert_problem(r, 422, "got (32, 32)")
    # other errors still listed with the shape line
    r = client.post("/sessions/s/touch", json={"frames": frame, "t": "soon"})
    body = assert_problem(r, 422, "got (32, 32)", "body field 't'")


@pytest.mark.parametrize("shape", [(32, 32), (2, 16, 16), (1, 2, 16, 16)])
def test_npy_shapes_are_reported_as_sent(client, shape: tuple[int, ...]) -> None:
    r = client.post(
        "/sessions/s/touch",
        params={"t": 1.0},
        content=_npy(np.full(shape, 600, np.float32)),
        headers={"content-type": "application/x-npy"},
    )
    assert_problem(r, 422, f"has shape {shape}", "(K, 32, 32)", "(B, K, 32, 32)")


def test_search_hits_carry_match_and_the_bar(client) -> None:
    for i, note in enumerate(["put the mug on the shelf", "open the door", "a red ball"]):
        assert (
            client.post("/sessions/s/text", json={"text": note, "t": float(i)}).status_code == 201
        )
    client.post("/sessions/s/touch", json={"frames": window().tolist(), "t": 5.0})
    hits = client.get("/search", params={"q": "put the mug on the shelf", "k": 10}).json()["hits"]
    assert {h["sense"] for h in hits} == {"text", "touch"}
    for h in hits:
        best = max(x["score"] for x in hits if x["sense"] == h["sense"])
        floor = MATCH_Z.get(h["sense"], 3.0)
        if h["n"] is not None:  # a touch answer is a grasp: pooled scores have their own bar
            floor = GRASP_MATCH_Z.get(h["sense"], floor)
        bar = max(floor, RELATIVE_KEEP * best)
        assert h["bar"] == pytest.approx(bar)
        assert h["match"] is (h["score"] >= h["bar"])
    assert hits[0]["text"] == "put the mug on the shelf" and hits[0]["match"] is True
    assert any(not h["match"] for h in hits)  # listed, and said to be below the bar


def test_python_search_with_no_sense_is_an_error_like_http(client) -> None:
    memory = client.app.state.tactus.memory
    memory.add("s", "text", "a note", t=1.0)
    with pytest.raises(InvalidInputError, match="names no sense"):
        memory.search("a note", senses=[])
    assert client.get("/search", params={"q": "a note", "sense": ""}).status_code == 422


def test_unknown_session_is_404_for_every_question(client) -> None:
    client.post("/sessions/s/text", json={"text": "a note", "t": 1.0})
    for path in ("/last", "/first", "/count"):
        assert_problem(client.get(path, params={"q": "a note", "session": "nope"}), 404, "nope")
    assert_problem(client.get("/sessions/nope/timeline"), 404, "nope")
    assert client.get("/last", params={"q": "a note", "session": "s"}).status_code == 200


def test_timeline_episodes_is_a_read(client) -> None:
    memory = client.app.state.tactus.memory
    for i in range(4):
        client.post("/sessions/s/touch", json={"frames": window(seed=i).tolist(), "t": float(i)})
    version = memory.store.version()
    r = client.get("/sessions/s/timeline", params={"episodes": "true"})
    assert r.status_code == 200 and r.json()["episodes"]
    assert memory.store.version() == version  # nothing written
    assert client.post("/sessions/s/episodes").status_code == 200  # the explicit write
    assert memory.store.version() > version


def test_while_starting_probes_say_the_step_and_data_routes_push_back(tmp_path: Path) -> None:
    """A loader that waits on a gate: while it waits the app answers (this is what lets
    `tactus serve` open its socket at once); the real-server version is in
    tests/project/test_newcomer.py."""
    memory = make_memory(tmp_path / "m")
    gate = threading.Event()

    def loader(state) -> str | None:
        state.starting = "[3/3] loading the touch encoder"
        assert gate.wait(60)
        return None

    app = create_app(Settings(), memory=memory, loader=loader)
    with TestClient(app) as c:
        assert c.get("/live").status_code == 200
        r = c.get("/ready")
        assert_problem(r, 503, "starting", "[3/3] loading the touch encoder")
        assert r.headers["retry-after"] == "1"
        assert_problem(c.get("/health"), 503, "loading the touch encoder")
        r = c.get("/search", params={"q": "x"})
        assert_problem(r, 503, "starting", "touch encoder")
        assert r.headers["retry-after"] == "1"
        assert c.get("/").status_code == 200 and c.get("/openapi.json").status_code == 200
        gate.set()
        deadline = time.monotonic() + 180  # a liveness bound: a loaded machine loads slowly
        while c.get("/ready").status_code != 200 and time.monotonic() < deadline:
            threading.Event().wait(0.05)
        assert c.get("/ready").status_code == 200
        assert c.get("/search", params={"q": "x"}).status_code == 200
