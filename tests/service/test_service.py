"""The HTTP service through FastAPI's TestClient: HashingSpace + a stand-in touch sense."""

from __future__ import annotations

import io
import time
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from tactus_memory.errors import IdleWindowError, InvalidInputError
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import assert_problem, make_memory, npy_bytes, touch_json, window
from tests.helpers.threads import run_threads


# ----------------------------------------------------------------------------- writes & reads
def test_text_write_then_search(client):
    r = client.post(
        "/sessions/kitchen/text",
        json={"text": "the mug was hot", "t": 3.0, "t_end": 4.0, "meta": {"by": "op"}},
    )
    assert r.status_code == 201
    (item_id,) = r.json()["ids"]
    r = client.get("/search", params={"q": "hot mug", "k": 5})
    assert r.status_code == 200
    hit = r.json()["hits"][0]
    assert hit["id"] == item_id
    assert {"id", "session", "sense", "t", "t_end", "score", "meta"} <= hit.keys()
    assert (hit["session"], hit["sense"], hit["t"], hit["t_end"]) == ("kitchen", "text", 3.0, 4.0)
    assert hit["meta"] == {"by": "op"}


def test_text_with_id_is_idempotent(client):
    for _ in range(2):
        r = client.post("/sessions/s/text", json={"text": "note", "t": 1.0, "id": "note-1"})
        assert r.status_code == 201 and r.json()["ids"] == ["note-1"]
    assert client.get("/sessions/s").json()["n"] == 1


def test_touch_single_batch_and_npy(client):
    r = client.post("/sessions/g1/touch", json=touch_json(t=1.0, t_end=1.3, meta={"obj": "mug"}))
    assert r.status_code == 201 and r.json()["count"] == 1
    batch = {"windows": [window(seed=i).tolist() for i in range(3)], "t": [2.0, 3.0, 4.0]}
    r = client.post("/sessions/g1/touch", json=batch)
    assert r.status_code == 201 and r.json()["count"] == 3
    r = client.post(
        "/sessions/g1/touch",
        content=npy_bytes(window(seed=9).astype(np.uint16)),
        params={"t": 5.0, "t_end": 5.2},
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 201 and r.json()["count"] == 1
    stack = np.stack([window(seed=i) for i in range(4)])
    r = client.post(
        "/sessions/g1/touch",
        content=npy_bytes(stack),
        params=[("t", 6.0), ("t", 7.0), ("t", 8.0), ("t", 9.0)],
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 201 and len(r.json()["ids"]) == 4
    s = client.get("/sessions/g1").json()
    assert s["counts"] == {"touch": 9} and s["t_min"] == 1.0 and s["t_max"] == 9.0


def test_search_filters_by_sense_session_and_time(client):
    client.post("/sessions/a/text", json={"text": "red ball", "t": 1.0})
    client.post("/sessions/b/text", json={"text": "red ball", "t": 10.0})
    client.post("/sessions/a/touch", json=touch_json(t=2.0))
    hits = client.get("/search", params={"q": "red ball", "session": "b"}).json()["hits"]
    assert [h["session"] for h in hits] == ["b"]
    hits = client.get("/search", params={"q": "red ball", "after": 5, "before": 20}).json()["hits"]
    assert [h["t"] for h in hits] == [10.0]
    client.post("/senses", json={"name": "motion", "dim": 64})
    vec = {"sense": "motion", "vectors": [np.ones(64).tolist()], "t": [3.0]}
    assert client.post("/sessions/a/vectors", json=vec).status_code == 201
    everything = client.get("/search", params={"q": "red", "k": 50}).json()["hits"]
    assert {h["sense"] for h in everything} == {"touch", "text", "motion"}
    n_touch = sum(h["sense"] == "touch" for h in everything)
    hits = client.get("/search", params=[("q", "red"), ("sense", "touch"), ("k", 50)])
    assert [h["sense"] for h in hits.json()["hits"]] == ["touch"] * n_touch
    hits = client.get(
        "/search", params=[("q", "x"), ("sense", "touch"), ("sense", "text"), ("k", 50)]
    )
    senses = [h["sense"] for h in hits.json()["hits"]]
    assert set(senses) == {"touch", "text"} and len(senses) == len(everything) - 1


def test_search_like_frames_vector_and_text(client):
    ids = [
        client.post("/sessions/s/touch", json=touch_json(seed=i, t=float(i))).json()["ids"][0]
        for i in range(4)
    ]
    r = client.post("/search/like", json={"sense": "touch", "frames": window(seed=2).tolist()})
    assert r.status_code == 200
    assert r.json()["hits"][0]["id"] == ids[2]
    client.post("/sessions/s/text", json={"text": "soft sponge", "t": 1.0})
    r = client.post("/search/like", json={"sense": "text", "text": "soft sponge", "k": 1})
    assert r.json()["hits"][0]["sense"] == "text"
    client.post("/senses", json={"name": "motion", "dim": 64})
    vec = np.ones(64).tolist()
    client.post("/sessions/s/vectors", json={"sense": "motion", "vectors": [vec], "t": [1.0]})
    r = client.post("/search/like", json={"sense": "motion", "vector": vec, "k": 3})
    assert r.status_code == 200 and r.json()["hits"][0]["sense"] == "motion"


def test_register_vector_sense_and_store_vectors(client):
    r = client.post("/senses", json={"name": "motion", "dim": 64, "encoder": "imu-tcn"})
    assert r.status_code == 201
    assert r.json()["provenance"]["encoder"] == "imu-tcn"
    vecs = np.random.default_rng(0).standard_normal((3, 64)).tolist()
    r = client.post(
        "/sessions/s/vectors", json={"sense": "motion", "vectors": vecs, "t": [1.0, 2.0, 3.0]}
    )
    assert r.status_code == 201 and r.json()["count"] == 3
    senses = {s["name"]: s for s in client.get("/senses").json()["senses"]}
    assert senses["motion"]["rows"] == 3 and senses["motion"]["live"]
    assert senses["touch"]["provenance"]["encoder"] == "stand-in-touch"
    assert_problem(client.post("/senses", json={"name": "motion", "dim": 64}), 409, "motion")
    assert_problem(client.post("/senses", json={"name": "imu", "dim": 63}), 409, "dimension")


def test_sessions_list_get_delete(client):
    client.post("/sessions/a/text", json={"text": "one", "t": 1.0})
    client.post("/sessions/b/touch", json=touch_json(t=5.0))
    ids = [s["id"] for s in client.get("/sessions").json()["sessions"]]
    assert ids == ["a", "b"]
    r = client.delete("/sessions/a")
    assert r.status_code == 200 and r.json() == {"id": "a", "deleted": 1, "clock_offsets": 0}
    assert_problem(client.get("/sessions/a"), 404, "a")
    assert_problem(client.delete("/sessions/a"), 404)
    assert [s["id"] for s in client.get("/sessions").json()["sessions"]] == ["b"]


def test_health_and_openapi(client):
    h = client.get("/health").json()
    assert h["status"] == "ok" and h["touch"] is True and "text" in h["senses"]
    spec = client.get("/openapi.json").json()
    paths = spec["paths"]
    for p in (
        "/sessions/{session}/touch",
        "/sessions/{session}/text",
        "/search",
        "/search/like",
        "/sessions",
        "/senses",
        "/health",
    ):
        assert p in paths
    touch = paths["/sessions/{session}/touch"]["post"]
    assert "raw sensor units" in touch["description"].lower()
    assert "application/x-npy" in touch["requestBody"]["content"]
    assert "422" in touch["responses"] and "summary" in touch


# ----------------------------------------------------------------------------- bad inputs
BAD_JSON_TOUCH = [
    ({"frames": window()[:, :, :31].tolist(), "t": 1.0}, "(8, 32, 31)"),
    ({"frames": [[[1.0, 2.0], [3.0]]], "t": 1.0}, "ragged"),
    ({"frames": window().tolist()}, "t"),
    ({"t": 1.0}, "frames"),
    ({"windows": [window().tolist()], "t": [1.0, 2.0]}, "t has 2 entries"),
    ({"windows": [window().tolist(), window(k=4).tolist()], "t": [1.0, 2.0]}, "ragged"),
    ({"frames": window().tolist(), "t": 2.0, "t_end": 1.0}, "before"),
    ({"frames": window().tolist(), "t": 1.0, "colour": "red"}, "colour"),
    ([1, 2, 3], "object"),
]


@pytest.mark.parametrize(("body", "word"), BAD_JSON_TOUCH)
def test_bad_touch_json_is_422(client, body, word):
    assert_problem(client.post("/sessions/s/touch", json=body), 422, word)


@pytest.mark.parametrize(
    ("raw", "word"),
    [
        ('{"frames": [[[NaN]]], "t": 1}', "nan"),
        ('{"frames": [[[Infinity]]], "t": 1}', "infinity"),
        ('{"frames": [[[1.0]]], "t": -Infinity}', "infinity"),
        ('{"frames": [[[1.0]', "json"),
    ],
)
def test_nan_literals_and_broken_json_are_422(client, raw, word):
    r = client.post("/sessions/s/touch", content=raw, headers={"content-type": "application/json"})
    assert_problem(r, 422, word)


def test_nan_in_text_and_vectors_is_422(client):
    hdr = {"content-type": "application/json"}
    r = client.post("/sessions/s/text", content='{"text": "a", "t": NaN}', headers=hdr)
    assert_problem(r, 422, "finite")
    client.post("/senses", json={"name": "motion", "dim": 64})
    raw = '{"sense": "motion", "vectors": [[' + ", ".join(["1.0"] * 63 + ["NaN"]) + ']], "t": [1]}'
    assert_problem(client.post("/sessions/s/vectors", content=raw, headers=hdr), 422, "finite")


@pytest.mark.parametrize(
    ("body", "word"),
    [
        (npy_bytes(np.full((8, 32, 32), np.nan, np.float32)), "nan"),
        (npy_bytes(np.zeros((8, 32, 30), np.float32)), "(8, 32, 30)"),
        (npy_bytes(np.zeros((32, 32), np.float32)), "(32, 32)"),
        (b"not an npy file at all", "npy"),
        (b"", "empty"),
        (npy_bytes(np.array(["a", "b"])), "dtype"),
    ],
)
def test_bad_npy_is_422(client, body, word):
    r = client.post(
        "/sessions/s/touch",
        content=body,
        params={"t": 1.0},
        headers={"content-type": "application/x-npy"},
    )
    assert_problem(r, 422, word)


def test_npy_pickle_is_refused(client):
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    r = client.post(
        "/sessions/s/touch",
        content=buf.getvalue(),
        params={"t": 1.0},
        headers={"content-type": "application/x-npy"},
    )
    assert_problem(r, 422, "npy")


def test_npy_without_t_and_wrong_t_count_are_422(client):
    hdr = {"content-type": "application/x-npy"}
    assert_problem(
        client.post("/sessions/s/touch", content=npy_bytes(window()), headers=hdr), 422, "'t'"
    )
    stack = npy_bytes(np.stack([window(), window()]))
    r = client.post("/sessions/s/touch", content=stack, params={"t": 1.0}, headers=hdr)
    assert_problem(r, 422, "t has 1 entries for 2")


def test_unsupported_content_type_is_415(client):
    r = client.post("/sessions/s/touch", content=b"x", headers={"content-type": "text/csv"})
    assert_problem(r, 415, "text/csv")


def test_wrong_vector_dimension_is_422(client):
    client.post("/senses", json={"name": "motion", "dim": 64})
    body = {"sense": "motion", "vectors": [[1.0] * 10], "t": [1.0]}
    assert_problem(client.post("/sessions/s/vectors", json=body), 422, "dimension 10")
    r = client.post("/search/like", json={"sense": "motion", "vector": [1.0] * 3})
    assert_problem(r, 422, "dimension 3")


def test_unknown_sense_is_404(client):
    body = {"sense": "smell", "vectors": [[1.0] * 64], "t": [1.0]}
    assert_problem(client.post("/sessions/s/vectors", json=body), 404, "smell")
    client.post("/sessions/s/text", json={"text": "x", "t": 1.0})
    assert_problem(client.get("/search", params={"q": "x", "sense": "smell"}), 404, "smell")
    assert_problem(client.get("/search", params={"q": "x", "sense": "Bad-Name"}), 422, "sense")


@pytest.mark.parametrize(
    ("path", "body", "word"),
    [
        ("/sessions/s/text", {"t": 1.0}, "text"),
        ("/sessions/s/text", {"text": "", "t": 1.0}, "text"),
        ("/sessions/s/text", {"text": "x"}, "'t'"),
        ("/sessions/s/vectors", {"sense": "text", "t": [1.0]}, "vectors"),
        ("/senses", {"name": "motion"}, "dim"),
        ("/search/like", {"sense": "touch"}, "exactly one"),
        ("/search/like", {"sense": "touch", "vector": [1.0], "text": "x"}, "exactly one"),
    ],
)
def test_missing_fields_are_422(client, path, body, word):
    assert_problem(client.post(path, json=body), 422, word)


@pytest.mark.parametrize(
    ("params", "word"),
    [
        ({"q": "x", "k": 0}, "k"),
        ({"q": "x", "k": 1001}, "k"),
        ({"q": "x", "k": "ten"}, "k"),
        ({"q": "x", "after": 5, "before": 1}, "later than"),
        ({"q": "x", "after": "nan"}, "finite"),
        ({"q": "x", "before": "soon"}, "before"),
        ({"k": 3}, "q"),
        ({"q": ""}, "q"),
        ({"q": "x", "session": "../etc/passwd"}, "session"),
    ],
)
def test_bad_search_parameters_are_422(client, params, word):
    client.post("/sessions/s/text", json={"text": "x", "t": 1.0})
    assert_problem(client.get("/search", params=params), 422, word)


@pytest.mark.parametrize(
    "session",
    ["a b", "'; DROP TABLE items; --", "-lead", "x" * 129, "s%00", "caf\u00e9", ".hidden"],
)
def test_hostile_path_ids_are_422(client, session):
    assert_problem(
        client.post(f"/sessions/{session}/text", json={"text": "x", "t": 1}), 422, "session"
    )
    assert_problem(client.get(f"/sessions/{session}"), 422, "session")
    assert_problem(client.delete(f"/sessions/{session}"), 422, "session")


def test_hostile_item_id_is_422(client):
    r = client.post("/sessions/s/text", json={"text": "x", "t": 1, "id": "a' OR '1'='1"})
    assert_problem(r, 422, "id")


def test_oversized_body_by_content_length_is_413(client):
    big = b"{" + b" " * (3 * 1024 * 1024) + b"}"
    r = client.post("/sessions/s/text", content=big, headers={"content-type": "application/json"})
    assert_problem(r, 413, "limit")


def test_oversized_streamed_body_without_length_is_413(client):
    def chunks():
        for _ in range(40):
            yield b" " * (100 * 1024)

    r = client.post(
        "/sessions/s/touch",
        content=chunks(),
        headers={"content-type": "application/x-npy"},
        params={"t": 1.0},
    )
    assert "content-length" not in r.request.headers
    assert_problem(r, 413, "limit")
    r = client.post(
        "/sessions/s/text", content=chunks(), headers={"content-type": "application/json"}
    )
    assert_problem(r, 413, "limit")


def test_image_without_vision_is_400(client):
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (8, 8), (255, 0, 0)).save(buf, format="PNG")
    r = client.post(
        "/sessions/s/image",
        files={"file": ("x.png", buf.getvalue(), "image/png")},
        data={"t": "1.0"},
    )
    assert_problem(r, 400, "vision")


def test_touch_unavailable_is_503(tmp_path):
    memory = make_memory(tmp_path / "m", touch=False)
    with TestClient(create_app(Settings(), memory=memory)) as c:
        assert_problem(c.post("/sessions/s/touch", json=touch_json()), 503, "touch")
        with c.websocket_connect("/sessions/s/touch/stream") as ws:
            msg = ws.receive_json()
            assert msg["type"] == "error" and msg["error"]["status"] == 503
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.receive_json()
            assert exc.value.code == 1013
        assert c.get("/health").json()["touch"] is False
        # the rest of the service still works
        assert c.post("/sessions/s/text", json={"text": "x", "t": 1}).status_code == 201


def test_unexpected_error_is_500_problem(memory):
    class Broken:
        def __getattr__(self, name):
            return getattr(memory, name)

        def search(self, *a, **kw):
            raise RuntimeError("disk on fire")

    app = create_app(Settings(), memory=Broken())
    with TestClient(app, raise_server_exceptions=False) as c:
        body = assert_problem(c.get("/search", params={"q": "x"}), 500, "RuntimeError")
        assert "disk on fire" not in body["detail"]


# ----------------------------------------------------------------------------- auth
def test_token_required_everywhere_but_health(memory):
    app = create_app(Settings(token="s3cret"), memory=memory)
    with TestClient(app) as c:
        assert c.get("/health").status_code == 200
        good = {"Authorization": "Bearer s3cret"}
        for bad in ({}, {"Authorization": "Bearer nope"}, {"Authorization": "Basic s3cret"}):
            assert_problem(c.get("/sessions", headers=bad), 401, "token")
            assert_problem(c.get("/search", params={"q": "x"}, headers=bad), 401, "token")
            r = c.post("/sessions/s/text", json={"text": "x", "t": 1}, headers=bad)
            assert_problem(r, 401)
        assert c.get("/sessions", headers=good).status_code == 200
        assert (
            c.post("/sessions/s/text", json={"text": "x", "t": 1}, headers=good).status_code == 201
        )
        with c.websocket_connect("/sessions/s/touch/stream?token=nope") as ws:
            msg = ws.receive_json()
            assert msg["error"]["status"] == 401
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.receive_json()
            assert exc.value.code == 1008
        with c.websocket_connect("/sessions/s/touch/stream?token=s3cret") as ws:
            assert ws.receive_json()["type"] == "ready"
        with c.websocket_connect("/sessions/s/touch/stream", headers=good) as ws:
            assert ws.receive_json()["type"] == "ready"


# ----------------------------------------------------------------------------- live touch
def _frames(n: int, seed: int = 0) -> np.ndarray:
    return window(k=n, seed=seed)


def test_stream_windows_frames_and_acks(client):
    frames = _frames(20)
    with client.websocket_connect("/sessions/live/touch/stream?window=4&stride=2") as ws:
        ready = ws.receive_json()
        assert ready["type"] == "ready" and (ready["window"], ready["stride"]) == (4, 2)
        for i, f in enumerate(frames):
            ws.send_json({"frame": f.tolist(), "t": i / 30})
        acks = [ws.receive_json() for _ in range(9)]  # windows start at 0, 2, ..., 16
    assert all(a["type"] == "stored" for a in acks)
    assert [a["seq"] for a in acks] == list(range(9))
    assert acks[0]["t"] == 0.0 and acks[0]["t_end"] == pytest.approx(3 / 30)
    assert acks[-1]["t"] == pytest.approx(16 / 30) and acks[-1]["t_end"] == pytest.approx(19 / 30)
    s = client.get("/sessions/live").json()
    assert s["counts"] == {"touch": 9}
    # the stored window is exactly frames 2..5 (stand-in keeps raw as float16)
    like = client.post("/search/like", json={"sense": "touch", "frames": frames[2:6].tolist()})
    assert like.json()["hits"][0]["id"] == acks[1]["id"]


def test_stream_stride_larger_than_window_skips_frames(client):
    with client.websocket_connect("/sessions/live/touch/stream?window=2&stride=5") as ws:
        ws.receive_json()
        for i, f in enumerate(_frames(12)):
            ws.send_json({"frame": f.tolist(), "t": float(i)})
        acks = [ws.receive_json() for _ in range(3)]  # windows at frames 0, 5, 10
    assert [(a["t"], a["t_end"]) for a in acks] == [(0.0, 1.0), (5.0, 6.0), (10.0, 11.0)]


def test_stream_default_window_from_settings(memory):
    app = create_app(Settings(window=3, stride=3), memory=memory)
    with TestClient(app) as c, c.websocket_connect("/sessions/x/touch/stream") as ws:
        assert ws.receive_json()["window"] == 3
        for i, f in enumerate(_frames(6)):
            ws.send_json({"frame": f.tolist(), "t": float(i)})
        assert [ws.receive_json()["type"] for _ in range(2)] == ["stored", "stored"]


def test_stream_binary_npy_frames_with_hz(client):
    url = "/sessions/bin/touch/stream?window=4&stride=4&hz=10&t0=100"
    with client.websocket_connect(url) as ws:
        ws.receive_json()
        frames = _frames(8)
        for f in frames[:4]:
            ws.send_bytes(npy_bytes(f))
        ws.send_bytes(npy_bytes(frames[4:]))  # (4, 32, 32) in one message
        acks = [ws.receive_json() for _ in range(2)]
    assert [(a["t"], a["t_end"]) for a in acks] == [
        (100.0, pytest.approx(100.3)),
        (pytest.approx(100.4), pytest.approx(100.7)),
    ]


@pytest.mark.parametrize(
    ("message", "word"),
    [
        ({"frame": [[1.0] * 32] * 31, "t": 0.0}, "(31, 32)"),
        ({"frame": [[1.0] * 32] * 31 + [[1.0] * 5], "t": 0.0}, "ragged"),
        ({"frame": [[1.0] * 32] * 32}, "'t'"),
        ({"frame": [[1.0] * 32] * 32, "t": "noon"}, "'t'"),
        ({"frames": []}, "frame"),
        ("not json", "json"),
        ('{"frame": [[NaN]], "t": 0}', "nan"),
        (b"\x93NUMPY garbage", "npy"),
        (None, "nan"),
    ],
)
def test_stream_bad_frames_get_errors_and_stream_goes_on(client, message, word):
    with client.websocket_connect("/sessions/live/touch/stream?window=2&stride=2") as ws:
        ws.receive_json()
        if message is None:
            ws.send_bytes(npy_bytes(np.full((32, 32), np.inf, np.float32)))
        elif isinstance(message, bytes):
            ws.send_bytes(message)
        elif isinstance(message, str):
            ws.send_text(message)
        else:
            ws.send_json(message)
        err = ws.receive_json()
        assert err["type"] == "error" and err["error"]["status"] == 422
        assert word.lower() in err["error"]["detail"].lower(), err
        for i, f in enumerate(_frames(2)):
            ws.send_json({"frame": f.tolist(), "t": float(i)})
        assert ws.receive_json()["type"] == "stored"


@pytest.mark.parametrize(
    ("query", "word"),
    [
        ("window=0", "window"),
        ("stride=abc", "stride"),
        ("window=9999", "window"),
        ("hz=-1", "hz"),
        ("calibrated=maybe", "calibrated"),
        ("t0=nan", "t0"),
    ],
)
def test_stream_bad_parameters(client, query, word):
    with client.websocket_connect(f"/sessions/live/touch/stream?{query}") as ws:
        msg = ws.receive_json()
        assert msg["error"]["status"] == 422 and word in msg["error"]["detail"]
        with pytest.raises(WebSocketDisconnect) as exc:
            ws.receive_json()
        assert exc.value.code == 1008


def test_stream_hostile_session_id(client):
    with client.websocket_connect("/sessions/bad%20id/touch/stream") as ws:
        msg = ws.receive_json()
        assert msg["error"]["status"] == 422 and "session" in msg["error"]["detail"]


# ----------------------------------------------------------------------------- concurrency
def test_concurrent_writers_lose_nothing(client):
    n_threads, per_thread = 8, 6
    errors: list[str] = []

    def work(i: int) -> None:
        for j in range(per_thread):
            if j % 2:
                r = client.post(f"/sessions/c{i % 3}/text", json={"text": f"n {i} {j}", "t": j})
            else:
                r = client.post(f"/sessions/c{i % 3}/touch", json=touch_json(seed=j, t=j))
            if r.status_code != 201:
                errors.append(r.text)

    run_threads(work, [(i,) for i in range(n_threads)])  # exceptions re-raised here
    assert not errors
    total = sum(s["n"] for s in client.get("/sessions").json()["sessions"])
    assert total == n_threads * per_thread


def test_concurrent_streams_lose_nothing(client):
    n_streams, n_frames = 6, 16
    counts: list[int] = []

    def stream(i: int) -> None:
        with client.websocket_connect(f"/sessions/g{i}/touch/stream?window=4&stride=4") as ws:
            ws.receive_json()
            for j, f in enumerate(_frames(n_frames, seed=i)):
                ws.send_json({"frame": f.tolist(), "t": j / 30})
            counts.append(sum(ws.receive_json()["type"] == "stored" for _ in range(4)))

    run_threads(stream, [(i,) for i in range(n_streams)])  # exceptions re-raised here
    assert counts == [4] * n_streams
    sessions = client.get("/sessions").json()["sessions"]
    assert sum(s["n"] for s in sessions) == n_streams * n_frames // 4


def test_stream_oversized_message_is_an_error_not_a_drop(memory):
    app = create_app(Settings(max_ws_message_bytes=4096), memory=memory)
    with TestClient(app) as c, c.websocket_connect("/sessions/x/touch/stream?window=1") as ws:
        ws.receive_json()
        ws.send_bytes(npy_bytes(np.zeros((4, 32, 32), np.float32)))  # 16 KiB
        err = ws.receive_json()
        assert err["error"]["status"] == 422 and "limit" in err["error"]["detail"]
        ws.send_bytes(npy_bytes(np.full((32, 32), 0.5, np.float16)))  # a touching frame
        assert ws.receive_json()["type"] == "stored"


# ----------------------------------------------------------------------------- settings & CLI
def test_settings_from_environment(monkeypatch):
    monkeypatch.setenv("TACTUS_DATA", "/srv/mem")
    monkeypatch.setenv("TACTUS_TOKEN", "abc")
    monkeypatch.setenv("TACTUS_MAX_BODY_BYTES", "5000")
    monkeypatch.setenv("TACTUS_WINDOW", "16")
    monkeypatch.setenv("TACTUS_STRIDE", "4")
    s = Settings()
    assert (s.data, s.max_body_bytes, s.window, s.stride) == ("/srv/mem", 5000, 16, 4)
    assert s.token is not None and s.token.get_secret_value() == "abc"
    assert "abc" not in repr(s)


def test_settings_file_then_environment_then_flags(monkeypatch, tmp_path):
    """One settings object, three places: a TOML file (--config / TACTUS_CONFIG), the
    environment over it, keyword arguments (the CLI's flags) over both."""
    for name in ("TACTUS_DATA", "TACTUS_WINDOW", "TACTUS_STRIDE", "TACTUS_RETAIN_SECONDS"):
        monkeypatch.delenv(name, raising=False)
    path = tmp_path / "tactus.toml"
    path.write_text('data = "/from/file"\nwindow = 4\nstride = 3\nretain_seconds = 99.0\n')
    monkeypatch.setenv("TACTUS_CONFIG", str(path))
    monkeypatch.setenv("TACTUS_STRIDE", "2")
    s = Settings(window=6)
    assert (s.data, s.window, s.stride) == ("/from/file", 6, 2)
    assert s.maintenance().retain_seconds == 99.0
    monkeypatch.delenv("TACTUS_CONFIG")
    assert Settings(config=str(path)).data == "/from/file"
    with pytest.raises(ValueError, match="no settings file"):
        Settings(config=str(tmp_path / "missing.toml"))


def test_serve_command_builds_settings_and_runs_uvicorn(monkeypatch, tmp_path):
    from typer.testing import CliRunner

    import tactus_memory.cli.serve_cmd as serve_cmd
    from tactus_memory.cli import app as cli_app

    seen: dict[str, Any] = {}
    monkeypatch.setenv("TACTUS_STRIDE", "2")
    monkeypatch.setattr(
        serve_cmd, "load_app", lambda settings, say: seen.setdefault("settings", settings)
    )
    monkeypatch.setattr(serve_cmd, "run_server", lambda app, settings: seen.update(ran=settings))
    args = ["serve", "--workers", "1", "--port", "8123", "--data", str(tmp_path)]
    args += ["--token", "T", "--no-touch"]
    result = CliRunner().invoke(cli_app, args)
    assert result.exit_code == 0, result.output
    s = seen["settings"]
    assert (s.port, s.data, s.stride, s.touch) == (8123, str(tmp_path), 2, False)
    assert s.token.get_secret_value() == "T"
    assert seen["ran"] is s and (s.host, s.port) == ("127.0.0.1", 8123)


def test_serve_loads_step_by_step_and_names_the_page(monkeypatch, tmp_path):
    from tactus_memory.cli.serve_cmd import load_app, page_url
    from tests.helpers.fakes import HashingSpace

    monkeypatch.setattr("tactus_memory.spaces.get_space", lambda name: HashingSpace(dim=32))
    lines: list[str] = []
    app = load_app(Settings(data=str(tmp_path / "m"), touch=False), say=lines.append)
    # the store opens first; the models load once the app runs (the socket is open by then)
    assert [ln.split(" ", 1)[0] for ln in lines if "done in" in ln] == ["[1/3]"]
    with TestClient(app) as c:
        assert c.get("/live").status_code == 200
        deadline = time.monotonic() + 180  # a liveness bound: a loaded machine loads slowly
        while c.get("/ready").status_code != 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert c.get("/ready").status_code == 200
        assert "TACTUS_TOUCH" in c.get("/health").json()["touch_unavailable"]
    assert [ln.split(" ", 1)[0] for ln in lines if "done in" in ln] == ["[1/3]", "[2/3]", "[3/3]"]
    assert any("loading the text model" in ln for ln in lines)
    assert any(ln.startswith("touch is off") and "TACTUS_TOUCH" in ln for ln in lines)
    assert page_url(Settings(host="0.0.0.0", port=9000)) == "http://127.0.0.1:9000/"
    assert page_url(Settings(host="::1", port=9000), 9001) == "http://[::1]:9001/"


def test_fresh_store_registers_default_senses_and_explains_missing_touch(tmp_path, monkeypatch):
    import tactus_memory.service.app as app_module
    from tests.helpers.fakes import HashingSpace

    monkeypatch.setattr("tactus_memory.spaces.get_space", lambda name: HashingSpace(dim=32))
    app = app_module.create_app(Settings(data=str(tmp_path / "fresh"), touch=False))
    with TestClient(app) as c:
        h = c.get("/health").json()
        assert "text" in h["senses"] and h["touch"] is False
        assert "TACTUS_TOUCH" in h["touch_unavailable"]
        assert_problem(c.post("/sessions/s/touch", json=touch_json()), 503, "TACTUS_TOUCH")


def test_stream_bad_window_in_a_batch_does_not_sink_its_neighbours(client, memory):
    """Windows the sense refuses at commit time are reported one by one; the rest are stored."""
    real_validate = memory.senses["touch"].validate

    def picky(item):
        if float(np.asarray(item).max()) > 10_000:
            raise InvalidInputError("window too hot")
        return real_validate(item)

    memory.senses["touch"].validate = picky  # the stand-in validates only inside the memory
    with client.websocket_connect("/sessions/mix/touch/stream?window=1&stride=1") as ws:
        ws.receive_json()
        for i in range(6):
            frame = np.full((32, 32), 20_000.0 if i == 3 else 600.0 + i)  # in contact
            ws.send_bytes(npy_bytes(frame))
        msgs = [ws.receive_json() for _ in range(6)]
    assert sorted(m["seq"] for m in msgs if m["type"] == "stored") == [0, 1, 2, 4, 5]
    (err,) = [m for m in msgs if m["type"] == "error"]
    assert err["windows"] == [3] and "too hot" in err["error"]["detail"]


def test_search_reports_library_time_in_server_timing(client):
    client.post("/sessions/s/text", json={"text": "a red ball", "t": 1.0})
    r = client.get("/search", params={"q": "red"})
    name, _, dur = r.headers["server-timing"].partition(";dur=")
    assert name == "library" and float(dur) > 0


def test_stream_idle_windows_are_acknowledged_not_stored(memory):
    """A resting glove (no contact) gives "idle" acks; only the touching window is stored."""
    app = create_app(Settings(), memory=memory)
    rest = np.full((32, 32), 512, np.int16)  # raw resting reading, no taxel in contact
    press = rest.copy()
    press[:4, :4] = 620
    with (
        TestClient(app) as c,
        c.websocket_connect("/sessions/idle/touch/stream?window=2&stride=2") as ws,
    ):
        ws.receive_json()
        for f in (rest, rest, press, press):
            ws.send_bytes(npy_bytes(f))
        first, second = ws.receive_json(), ws.receive_json()
    assert first["type"] == "idle" and first["seq"] == 0
    assert second["type"] == "stored" and second["seq"] == 1
    assert [it.sense for it in memory.timeline("idle")] == ["touch"]


def test_idle_windows_are_skipped_the_same_way_from_every_entry_point(memory):
    """The idle rule is the touch sense's: the same resting window alone is skipped over HTTP
    (JSON and .npy: 201 with ``skipped: [{index 0, idle}]``, as in a batch) and acknowledged
    "idle" on the stream (above); Python's ``Memory.add`` raises IdleWindowError. Nothing is
    stored, and a window with contact is."""
    rest = np.full((2, 32, 32), 512, np.int16)  # raw resting reading, no taxel in contact
    with pytest.raises(IdleWindowError):
        memory.add("py", "touch", rest, t=1.0)
    app = create_app(Settings(), memory=memory)
    skipped = [{"index": 0, "reason": "idle"}]
    with TestClient(app) as c:
        r = c.post("/sessions/http/touch", json={"frames": rest.tolist(), "t": 1.0})
        assert r.status_code == 201 and r.json() == {"ids": [], "count": 0, "skipped": skipped}
        headers = {"content-type": "application/x-npy"}
        r = c.post("/sessions/http/touch?t=1", content=npy_bytes(rest), headers=headers)
        assert r.status_code == 201 and r.json()["skipped"] == skipped, r.text
        r = c.post("/sessions/http/touch", json={"windows": [rest.tolist()], "t": [1.0]})
        assert r.status_code == 201 and r.json()["skipped"] == skipped, r.text
        press = rest.copy()
        press[:, :4, :4] = 620
        r = c.post("/sessions/http/touch", json={"frames": press.tolist(), "t": 2.0})
        assert r.status_code == 201 and r.json()["skipped"] == [], r.text
    assert {s.id: s.n for s in memory.sessions()} == {"http": 1}


def test_the_service_rebuilds_the_senses_its_store_records(tmp_path):
    """A reopened store's senses come back live from their records (the plug-in registry),
    not only the ones the service knows by name: a "motion" VectorSense added in Python takes
    vectors over HTTP after a restart."""
    from tactus_memory.adapters.vectors import VectorSense
    from tactus_memory.memory.main import Memory

    path = str(tmp_path / "mem")
    with Memory.open(path, background=False) as mem:
        mem.add_sense(VectorSense("motion", dim=mem.space.dim, encoder="imu-net"))
    app = create_app(Settings(data=path, touch=False))
    memory = app.state.tactus.memory
    assert memory.senses["motion"].provenance()["encoder"] == "imu-net"
    with TestClient(app) as client:
        vec = [0.0] * memory.space.dim
        vec[3] = 1.0
        body = {"sense": "motion", "vectors": [vec], "t": [1.0]}
        r = client.post("/sessions/s1/vectors", json=body)
        assert r.status_code == 201, r.text
