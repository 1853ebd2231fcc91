"""The service with the REAL touch sense (``TactusEncoder``) on a tiny random checkpoint:
raw vs calibrated windows, the calibrated flag, K limits, text search over touch, streaming."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import DIM, FRAMES, assert_problem, npy_bytes, window


@pytest.fixture
def client(tmp_path, checkpoint):
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tests.helpers.fakes import HashingSpace

    memory = Memory.open(str(tmp_path / "mem"), space=HashingSpace(dim=DIM))
    memory.add_sense(TactusEncoder(checkpoint))
    with TestClient(create_app(Settings(window=FRAMES, stride=FRAMES), memory=memory)) as c:
        yield c


def raw_window(seed: int = 0) -> np.ndarray:
    return window(k=FRAMES, seed=seed, base=520.0)  # raw STAG units, ~520-570


def test_raw_and_calibrated_windows_store_the_same_thing(client):
    raw = raw_window()
    calibrated = np.clip((raw - 500.0) / 150.0, 0, 1)
    a = client.post("/sessions/g/touch", json={"frames": raw.tolist(), "t": 1.0})
    b = client.post(
        "/sessions/g/touch", json={"frames": calibrated.tolist(), "t": 2.0, "calibrated": True}
    )
    c = client.post(
        "/sessions/g/touch",
        content=npy_bytes(raw.astype(np.uint16)),
        params={"t": 3.0},
        headers={"content-type": "application/x-npy"},
    )
    assert a.status_code == b.status_code == c.status_code == 201, (a.text, b.text, c.text)
    r = client.post("/search/like", json={"sense": "touch", "frames": raw.tolist(), "k": 3})
    hits = r.json()["hits"]
    assert len(hits) == 3 and all(h["cosine"] > 0.99 for h in hits)
    provenance = {s["name"]: s for s in client.get("/senses").json()["senses"]}["touch"]
    assert provenance["provenance"]["encoder"] == "tactus"
    assert provenance["provenance"]["checkpoint_sha256"]


def test_calibrated_flag_is_honoured(client):
    calibrated = np.clip((raw_window() - 500.0) / 150.0, 0, 1)
    # values in [0, 1] sent as raw (the default): the max-scaling defect, named
    r = client.post("/sessions/g/touch", json={"frames": calibrated.tolist(), "t": 1.0})
    assert_problem(r, 422, "calibrated")
    # raw values sent as calibrated
    body = {"frames": raw_window().tolist(), "t": 1.0, "calibrated": True}
    assert_problem(client.post("/sessions/g/touch", json=body), 422, "[0, 1]")


def test_too_many_frames_and_no_signal_are_422(client):
    body = {"frames": window(k=FRAMES + 1).tolist(), "t": 1.0}
    assert_problem(client.post("/sessions/g/touch", json=body), 422, "frames")
    flat = np.full((FRAMES, 32, 32), 480.0)
    r = client.post("/sessions/g/touch", json={"frames": flat.tolist(), "t": 1.0})
    assert_problem(r, 422, "offset")


def test_text_search_reaches_touch_rows(client):
    touch_id = client.post(
        "/sessions/g/touch", json={"frames": raw_window().tolist(), "t": 1.0}
    ).json()["ids"][0]
    # other senses in the store, so the filter has something to exclude
    for note in ("holding a mug", "a mug on the table"):
        assert client.post("/sessions/g/text", json={"text": note, "t": 2.0}).status_code == 201
    r = client.get("/search", params={"q": "holding a mug", "sense": "touch", "k": 10})
    assert r.status_code == 200
    assert [(h["id"], h["sense"]) for h in r.json()["hits"]] == [(touch_id, "touch")]
    r = client.get("/search", params={"q": "holding a mug", "k": 10})
    assert {h["sense"] for h in r.json()["hits"]} == {"touch", "text"}


def test_stream_with_real_encoder(client):
    frames = raw_window().astype(np.uint16)
    with client.websocket_connect("/sessions/live/touch/stream") as ws:
        assert ws.receive_json()["window"] == FRAMES
        for f in frames:
            ws.send_bytes(npy_bytes(f))
        for i in range(FRAMES):  # a window already in [0, 1] on a raw stream: refused, named
            ws.send_json({"frame": (np.zeros((32, 32)) + 0.5).tolist(), "t": 9.0 + i})
        for f in frames:
            ws.send_bytes(npy_bytes(f))
        msgs = [ws.receive_json() for _ in range(3)]
    stored = sorted(m["seq"] for m in msgs if m["type"] == "stored")
    (err,) = [m for m in msgs if m["type"] == "error"]
    assert stored == [0, 2], msgs
    assert err["error"]["status"] == 422 and err["windows"] == [1]
    assert "calibrated" in err["error"]["detail"]
