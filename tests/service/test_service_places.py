"""Places over HTTP (issue 23): poses in (JSON and .npy), near=/frame= on search and temporal
routes, /where and /at. TestClient with the hashing space; the last test runs the real
server (uvicorn, real MiniLM, real LanceDB)."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.places import POSES, T
from tests.helpers.service import assert_problem, make_memory, npy_bytes

NOTES = [("picked up the red drill", 2.0), ("put the mug on the shelf", 10.0)]


@pytest.fixture
def client(tmp_path):
    memory = make_memory(tmp_path / "mem", touch=False)
    with TestClient(create_app(Settings(max_body_bytes=2 * 1024 * 1024), memory=memory)) as c:
        yield c


def _notes(c: TestClient, session: str = "s1") -> None:
    for text, t in NOTES:
        assert c.post(f"/sessions/{session}/text", json={"text": text, "t": t}).status_code == 201


def test_npy_poses_backfill_and_search_near(client) -> None:
    _notes(client)
    r = client.post(
        "/sessions/s1/poses?frame=map&source=odom",
        content=npy_bytes(POSES),
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 201, r.text
    assert r.json() == {"session": "s1", "count": T.size}
    hits = client.get("/search", params={"q": "red drill", "near": "2,0,0,0.5"}).json()["hits"]
    assert [(h["text"], h["position"], h["frame"]) for h in hits] == [
        ("picked up the red drill", [2.0, 0.0, 0.0], "map")
    ]
    assert client.get("/search", params={"q": "drill", "near": "5,0,0,1"}).json()["hits"] == []
    assert client.get("/search", params={"q": "drill", "frame": "odom"}).json()["hits"] == []
    traj = client.get("/sessions/s1/poses").json()["trajectories"]
    assert [(tr["frame"], len(tr["t"])) for tr in traj] == [("map", T.size)]
    assert traj[0]["orientation"] is None


def test_json_poses_with_orientation_and_explicit_text_position(client) -> None:
    body = {
        "t": [0.0, 1.0],
        "position": [[0, 0, 0], [1, 0, 0]],
        "orientation": [[0, 0, 0, 1], [0, 0, 0.7071067811865476, 0.7071067811865476]],
        "frame": "odom",
    }
    assert client.post("/sessions/s2/poses", json=body).status_code == 201
    r = client.post(
        "/sessions/s2/text",
        json={"text": "the door", "t": 0.5, "position": [9, 9, 9], "frame": "map"},
    )
    assert r.status_code == 201
    client.post("/sessions/s2/text", json={"text": "the drill", "t": 0.5})
    items = client.get("/sessions/s2/timeline").json()["items"]
    by_text = {it["text"]: (it["position"], it["frame"]) for it in items}
    assert by_text == {"the door": ([9.0, 9.0, 9.0], "map"), "the drill": ([0.5, 0.0, 0.0], "odom")}
    placed = client.get("/sessions/s2/timeline", params={"near": "0.5,0,0,0.1"}).json()
    assert [it["text"] for it in placed["items"]] == ["the drill"]


def test_where_at_and_temporal_routes_take_near(client) -> None:
    _notes(client)
    client.post("/sessions/s1/poses", json={"t": POSES[:, 0].tolist(),
                                             "position": POSES[:, 1:].tolist()})  # fmt: skip
    places = client.get("/where", params={"q": "red drill", "session": "s1"}).json()
    assert places["places"][0]["position"] == [2.0, 0.0, 0.0]
    assert places["places"][0]["evidence"][0]["text"] == "picked up the red drill"
    at = client.get("/at", params={"x": 10, "y": 0, "z": 0, "r": 0.5}).json()
    assert [it["text"] for it in at["items"]] == ["put the mug on the shelf"]
    assert (
        client.get("/at", params={"x": 10, "y": 0, "z": 0, "r": 0.5, "session": "s9"}).json()[
            "items"
        ]
        == []
    )
    count = {near: client.get("/count", params={"q": "the mug", "near": near}).json()["count"]
             for near in ("10,0,0,0.5", "2,0,0,0.5")}  # fmt: skip
    assert count == {"10,0,0,0.5": 1, "2,0,0,0.5": 0}
    moments = client.get("/moments", params={"q": "drill", "near": "2,0,0,0.5"}).json()
    assert [m["position"] for m in moments["moments"]] == [[2.0, 0.0, 0.0]]
    client.delete("/sessions/s1")
    assert client.get("/sessions/s1/poses").status_code == 404  # items and poses gone


@pytest.mark.parametrize(
    ("body", "ctype", "status", "words"),
    [
        ({"t": [1.0, 0.5], "position": [[0, 0, 0]] * 2}, None, 422, ("unsorted",)),
        ({"t": [1.0, 1.0], "position": [[0, 0, 0]] * 2}, None, 422, ("duplicate",)),
        ({"t": [0.0], "position": [[0, 0, 0]] * 2}, None, 422, ("2 rows for 1",)),
        ({"t": [0.0], "position": [[0, 0, 0]], "orientation": [[0, 0, 0, 0.5]]}, None, 422,
         ("unit quaternion",)),
        ({"t": [0.0], "position": [[0, 0]]}, None, 422, ("position",)),
        (npy_bytes(np.zeros((3, 5))), "application/x-npy", 422, ("(N, 4)",)),
        (npy_bytes(np.array([[0, np.nan, 0, 0.0]])), "application/x-npy", 422, ("NaN",)),
        (b"not npy", "application/x-npy", 422, ("magic",)),
        (b"x", "text/plain", 415, ("content type",)),
    ],
)  # fmt: skip
def test_bad_poses_are_problems_and_nothing_is_written(client, body, ctype, status, words):
    if ctype is None:
        r = client.post("/sessions/s1/poses", json=body)
    else:
        r = client.post("/sessions/s1/poses", content=body, headers={"content-type": ctype})
    assert_problem(r, status, *words)
    assert client.get("/sessions/s1/poses").status_code == 404  # nothing stored


@pytest.mark.parametrize("near", ["1,2,3", "1,2,3,0", "a,b,c,d", "1,2,3,-1", "1,2,nan,1"])
def test_bad_near_is_a_422(client, near) -> None:
    _notes(client)
    assert_problem(client.get("/search", params={"q": "drill", "near": near}), 422, "near")


def test_bad_frame_is_a_422(client) -> None:
    r = client.get("/search", params={"q": "drill", "frame": "map' OR 1=1"})
    assert_problem(r, 422, "frame")


@pytest.mark.slow
def test_real_server_poses_where_and_at(tmp_path) -> None:
    import httpx

    from tests.helpers.servers import Server

    server = Server(tmp_path / "memory", tmp_path / "server.log")
    try:
        with httpx.Client(base_url=server.base, timeout=60) as c:
            _notes(c, "kitchen")  # type: ignore[arg-type]
            r = c.post(
                "/sessions/kitchen/poses",
                content=npy_bytes(POSES),
                headers={"content-type": "application/x-npy"},
            )
            assert r.status_code == 201, r.text
            where = c.get("/where", params={"q": "where was the drill?", "k": 1}).json()
            assert where["places"][0]["position"] == [2.0, 0.0, 0.0]
            at = c.get("/at", params={"x": 10, "y": 0, "z": 0, "r": 1}).json()
            assert [it["text"] for it in at["items"]] == ["put the mug on the shelf"]
            hits = c.get("/search", params={"q": "a mug", "near": "10,0,0,1"}).json()["hits"]
            assert [h["position"] for h in hits] == [[10.0, 0.0, 0.0]]
    finally:
        server.stop()


def test_at_takes_its_place_once(client) -> None:
    r = client.get("/at", params={"x": 0, "y": 0, "z": 0, "r": 1, "near": "0,0,0,1"})
    assert_problem(r, 422, "drop near")
    assert_problem(client.get("/at", params={"x": 0, "y": 0, "z": 0, "r": 0}), 422)
