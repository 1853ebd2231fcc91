"""Issue 39 (ingest) and "one pass through a write": the touch sense checks a (B, K, 32, 32)
batch in one numpy pass with the same windows, idle indices and errors as window by window;
a touch POST and a WebSocket message are parsed and validated off the event loop, once; a
binary message or ``.npy`` body of several frames or windows is one array; ``tactus serve``
defaults to one worker per core, capped."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import DynamicRangeError, IdleWindowError, InvalidInputError
from tactus_memory.service.app import create_app
from tactus_memory.settings import MAX_DEFAULT_WORKERS, Settings, default_workers
from tests.helpers.service import DIM, FRAMES, npy_bytes


@pytest.fixture
def encoder(checkpoint):  # noqa: F811  (the imported fixture)
    from tactus_memory.adapters.touch import TactusEncoder

    return TactusEncoder(checkpoint)


@pytest.fixture
def client(tmp_path: Path, encoder):
    from tactus_memory.memory.main import Memory
    from tests.helpers.fakes import HashingSpace

    memory = Memory.open(str(tmp_path / "mem"), space=HashingSpace(dim=DIM))
    memory.add_sense(encoder)
    with TestClient(create_app(Settings(window=FRAMES, stride=FRAMES), memory=memory)) as c:
        yield c


def batch(b: int, seed: int = 0, idle: tuple[int, ...] = ()) -> np.ndarray:
    """(b, FRAMES, 32, 32) raw STAG windows (uint16, grasp-like); ``idle`` ones at rest."""
    rng = np.random.default_rng(seed)
    out = (505 + rng.integers(0, 10, (b, FRAMES, 32, 32))).astype(np.uint16)
    for i in range(b):
        if i not in idle:
            out[i, :, 8:20, 10:22] = 600 + rng.integers(0, 80, (FRAMES, 12, 12))
    return out


def one_by_one(encoder, items: np.ndarray, **opts: Any) -> tuple[list[np.ndarray], list[int]]:
    canon, idle = [], []
    for i, w in enumerate(items):
        try:
            canon.append(encoder.validate(w, **opts))
        except IdleWindowError:
            idle.append(i)
    return canon, idle


@pytest.mark.parametrize("dtype", [np.uint16, np.float32, np.float64])
@pytest.mark.parametrize("calibrated", [None, False])
def test_a_batch_is_validated_in_one_pass_as_window_by_window(encoder, dtype, calibrated) -> None:
    items = batch(9, idle=(0, 4, 8)).astype(dtype)
    got, idle = encoder.validate_many(items, calibrated=calibrated)
    want, want_idle = one_by_one(encoder, items, calibrated=calibrated)
    assert idle == want_idle == [0, 4, 8]
    assert len(got) == len(want) == 6
    for a, b in zip(got, want, strict=True):
        assert type(a) is type(b) and a.dtype == np.float32 and np.array_equal(a, b)


def test_a_calibrated_batch_keeps_its_values(encoder) -> None:
    items = batch(3).astype(np.float32)
    cal = (items - 500) / 150.0
    cal = np.clip(cal, 0, 1).astype(np.float32)
    got, idle = encoder.validate_many(cal, calibrated=True)
    assert idle == [] and all(np.array_equal(g, c) for g, c in zip(got, cal, strict=True))
    got_auto, _ = encoder.validate_many(cal)  # floats in [0, 1]: taken as calibrated
    assert all(np.array_equal(g, c) for g, c in zip(got_auto, cal, strict=True))


def test_a_batch_never_checks_window_by_window(encoder, monkeypatch) -> None:
    """The vectorised path is taken: ``validate`` (one window) is never called for a good
    (B, K, 32, 32) array, and is for a list of windows."""
    calls = []
    real = type(encoder).validate
    monkeypatch.setattr(
        type(encoder), "validate", lambda self, w, **kw: calls.append(1) or real(self, w, **kw)
    )
    encoder.validate_many(batch(16, idle=(3,)), calibrated=False)
    assert calls == []
    encoder.validate_many(list(batch(4)), calibrated=False)
    assert len(calls) == 4


def test_batch_errors_are_the_first_bad_window_s_own(encoder) -> None:
    items = batch(5).astype(np.float32)
    items[3] = 0.5  # already in [0, 1] on a raw batch
    with pytest.raises(DynamicRangeError) as many:
        encoder.validate_many(items, calibrated=False)
    with pytest.raises(DynamicRangeError) as one:
        encoder.validate(items[3], calibrated=False)
    assert str(many.value) == str(one.value)
    items[1, 0, 0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN or inf"):
        encoder.validate_many(items, calibrated=False)
    with pytest.raises(InvalidInputError, match=rf"has {3 * FRAMES} frames"):
        encoder.validate_many(np.concatenate([batch(2)] * 3, axis=1), calibrated=False)
    with pytest.raises(IdleWindowError):  # one window alone: idle raises
        encoder.validate_many(batch(3, idle=(2,)), calibrated=False, skip_idle=False)
    _, idle = encoder.validate_many(batch(3, idle=(2,)), calibrated=False, keep_idle=True)
    assert idle == []


def _off_the_loop(monkeypatch, module: Any, name: str) -> list[bool]:
    """Wrap ``module.name`` to record, per call, whether it ran with no event loop running
    in its thread (a worker thread) or on the loop."""
    seen: list[bool] = []
    real = getattr(module, name)

    def wrapped(*a: Any, **kw: Any) -> Any:
        try:
            asyncio.get_running_loop()
            seen.append(False)
        except RuntimeError:
            seen.append(True)
        return real(*a, **kw)

    monkeypatch.setattr(module, name, wrapped)
    return seen


def test_an_npy_body_of_many_windows_is_one_write_off_the_loop(client, monkeypatch) -> None:
    import tactus_memory.service.routers.touch as route

    seen = _off_the_loop(monkeypatch, route, "window_write")
    items = batch(12, idle=(5,))
    r = client.post(
        "/sessions/s/touch",
        params={"t": [float(i) for i in range(12)]},
        content=npy_bytes(items),
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["count"] == 11 and body["skipped"] == [{"index": 5, "reason": "idle"}]
    assert seen == [True]
    summary = client.get("/sessions/s").json()
    assert summary["counts"] == {"touch": 11} and (summary["t_min"], summary["t_max"]) == (0, 11)
    # errors keep their words: the shape as sent, a missing t, a bad content type
    r = client.post(
        "/sessions/s/touch",
        params={"t": 1.0},
        content=npy_bytes(np.zeros((2, 16, 16), np.float32)),
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 422 and "(2, 16, 16)" in r.json()["detail"]
    r = client.post(
        "/sessions/s/touch",
        content=npy_bytes(items[0]),
        headers={"content-type": "application/x-npy"},
    )
    assert r.status_code == 422 and "'t' is required" in r.json()["detail"]
    r = client.post("/sessions/s/touch", content=b"x", headers={"content-type": "text/plain"})
    assert r.status_code == 415
    assert seen == [True] * 4


def test_json_window_and_batch_go_the_same_way(client) -> None:
    items = batch(3, idle=(1,))
    r = client.post("/sessions/j/touch", json={"frames": items[1].tolist(), "t": 1.0})
    assert r.status_code == 201 and r.json()["count"] == 0, r.text  # one idle window: skipped
    assert r.json()["skipped"] == [{"index": 0, "reason": "idle"}] and r.json()["ids"] == []
    r = client.post("/sessions/j/touch", json={"windows": items.tolist(), "t": [1.0, 2.0, 3.0]})
    assert r.status_code == 201 and r.json()["count"] == 2, r.text
    assert r.json()["skipped"] == [{"index": 1, "reason": "idle"}]


def test_a_binary_message_of_many_frames_is_windowed_off_the_loop(client, monkeypatch) -> None:
    """One binary message of 2.5 windows' frames: two windows stored at once (their times
    from ``hz``/``t0``), the rest waits for the next message. A message of several frames is
    parsed off the event loop, one small enough to parse faster than a thread hop on it; the
    windows are always validated and queued off the loop."""
    import tactus_memory.service.routers.touch_stream as stream

    seen = _off_the_loop(monkeypatch, stream, "_parse")
    queued = _off_the_loop(monkeypatch, stream, "_queue_windows")
    frames = batch(3).reshape(-1, 32, 32)  # (3 * FRAMES, 32, 32)
    first, rest = frames[: 2 * FRAMES + 2], frames[2 * FRAMES + 2 :]
    url = "/sessions/live/touch/stream?hz=10&t0=100"
    with client.websocket_connect(url) as ws:
        assert ws.receive_json()["type"] == "ready"
        ws.send_bytes(npy_bytes(first))
        acks = [ws.receive_json() for _ in range(2)]
        ws.send_bytes(npy_bytes(rest))
        acks.append(ws.receive_json())
        bad = first[:3].astype(np.float32)
        bad[1, 0, 0] = np.nan
        ws.send_bytes(npy_bytes(bad))
        err = ws.receive_json()
    assert [a["type"] for a in acks] == ["stored"] * 3, acks
    assert [a["seq"] for a in acks] == [0, 1, 2]
    step = 1 / 10
    for j, a in enumerate(acks):
        assert a["t"] == pytest.approx(100 + j * FRAMES * step)
        assert a["t_end"] == pytest.approx(100 + ((j + 1) * FRAMES - 1) * step)
    assert err["type"] == "error" and err["frame"] == 3 * FRAMES
    assert "NaN or inf" in err["error"]["detail"]
    # 10 frames (20 kB) off the loop, 2 (4 kB) on it, 3 float32 (12 kB) off it
    assert len(npy_bytes(rest)) <= stream.INLINE_BINARY_BYTES < len(npy_bytes(bad))
    assert seen == [True, False, True]
    assert queued == [True, True]  # the two messages that completed windows


def test_the_inline_limit_is_one_float64_frame() -> None:
    from tactus_memory.service.routers.touch_stream import INLINE_BINARY_BYTES

    assert len(npy_bytes(np.zeros((32, 32), np.float64))) == INLINE_BINARY_BYTES


def test_workers_default_to_the_cores_capped(monkeypatch) -> None:
    monkeypatch.delenv("TACTUS_WORKERS", raising=False)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert default_workers() == max(1, min(MAX_DEFAULT_WORKERS, cores or 1))
    assert Settings().workers == default_workers()
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    assert default_workers() == MAX_DEFAULT_WORKERS
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert Settings().workers == 1
    monkeypatch.setenv("TACTUS_WORKERS", "3")
    assert Settings().workers == 3
