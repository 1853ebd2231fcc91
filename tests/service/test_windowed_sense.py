"""A new windowed sense is served by one registration: a tiny IMU adapter defined here
(frames (6,): accelerometer xyz + gyro xyz), added with ``memory.add_sense`` and nothing else
(no route, schema or startup change), is written over HTTP (the generic windowed route, JSON
and ``.npy``) and over the WebSocket, refuses frames of another shape naming both, skips an
idle window, and is found by a text search, on a real uvicorn server in this process."""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from typing import Any

import httpx
import numpy as np
import pytest

from benchmarks.serving import serve_app
from tactus_memory.errors import IdleWindowError, InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.senses.base import array_to_bytes
from tactus_memory.senses.windowed import WindowedSense
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.spaces.base import Space
from tests.helpers.fakes import HashingSpace

#: gyro magnitude (rad/s) above which a window is "shaking", below which "turning slowly";
#: a window whose every reading is at rest (|accel - g| and |gyro| under IDLE) is idle
SHAKE, IDLE, G = 2.0, 0.05, 9.81


class TinyImu(WindowedSense):
    """(K, 6) windows -> the space's embedding of a word for how the IMU moved (deterministic)."""

    modality = "imu"

    def __init__(self, dim: int, name: str = "imu") -> None:
        self.name, self.dim = name, dim
        self.space: Space | None = None

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return (6,)

    def bind(self, space: Space) -> None:
        super().bind(space)
        self.space = space

    def is_idle(self, window: np.ndarray) -> bool:
        accel = np.linalg.norm(window[:, :3], axis=1) - G  # (K,)
        gyro = np.linalg.norm(window[:, 3:], axis=1)  # (K,)
        return bool((np.abs(accel) < IDLE).all() and (gyro < IDLE).all())

    def validate(self, item: Any) -> np.ndarray:
        window = self.parse_window(item)  # (K, 6) finite float32, or InvalidInputError
        if window.shape[0] < 2:
            raise InvalidInputError("an imu window is at least 2 frames")
        if self.is_idle(window):
            raise IdleWindowError("idle imu window: the device did not move")
        return window

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        assert self.space is not None
        gyro = [float(np.linalg.norm(w[:, 3:], axis=1).mean()) for w in batch]
        words = ["shaking hard" if g > SHAKE else "turning slowly" for g in gyro]
        return self.space.embed_texts(words)  # (N, D) unit rows

    def to_row(self, item: np.ndarray) -> dict[str, Any]:
        return {"raw": array_to_bytes(item)}


def imu_window(k: int, gyro: float, seed: int) -> np.ndarray:
    """(k, 6): gravity on z plus noise, the gyro spinning at about ``gyro`` rad/s on x."""
    rng = np.random.default_rng(seed)
    w = np.zeros((k, 6), np.float32)
    w[:, 2] = G
    w[:, :3] += 0.2 * rng.standard_normal((k, 3)).astype(np.float32)
    w[:, 3] = gyro
    return w


def npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Any:
    memory = Memory.open(str(tmp_path_factory.mktemp("imu") / "m"), space=HashingSpace(dim=64))
    memory.add_sense(TinyImu(64))  # the one registration
    app = create_app(Settings(), memory=memory)
    with serve_app(app, probe="/ready") as base:
        yield base, memory
    memory.close()


def test_an_imu_is_written_streamed_and_found_by_one_registration(served) -> None:
    base, memory = served
    with httpx.Client(base_url=base, timeout=60) as c:
        senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
        assert senses["imu"]["shape"] == [6] and senses["imu"]["modality"] == "imu"

        # HTTP, JSON: one window, then a batch whose second window is idle (skipped, named)
        url = "/sessions/desk/senses/imu/windows"
        r = c.post(url, json={"frames": imu_window(8, 5.0, 0).tolist(), "t": 1.0})
        assert r.status_code == 201, r.text
        shaking = r.json()["ids"]
        still = np.zeros((8, 6), np.float32)
        still[:, 2] = G
        batch = [imu_window(8, 0.3, 1).tolist(), still.tolist()]
        r = c.post(url, json={"windows": batch, "t": [2.0, 3.0], "meta": {"hand": "left"}})
        assert r.status_code == 201, r.text
        assert r.json()["count"] == 1 and r.json()["skipped"] == [{"index": 1, "reason": "idle"}]
        slow = r.json()["ids"]
        # HTTP, .npy: a (B, K, 6) batch
        r = c.post(url, params={"t": [4.0]}, content=npy(imu_window(8, 6.0, 2)[None]),
                   headers={"content-type": "application/x-npy"})  # fmt: skip
        assert r.status_code == 201, r.text
        shaking += r.json()["ids"]

        # frames of another shape: a 422 naming what was sent and the sense's (K, 6)
        r = c.post(url, json={"frames": np.zeros((8, 32, 32)).tolist(), "t": 5.0})
        assert r.status_code == 422 and "(8, 32, 32)" in r.json()["detail"], r.text
        assert "(K, 6)" in r.json()["detail"] and "'imu'" in r.json()["detail"]
        # the touch route is the same path for touch: no touch sense is served here
        r = c.post("/sessions/desk/senses/touch/windows", json={"frames": [[0.0] * 6], "t": 5})
        assert r.status_code == 503 and "touch" in r.json()["detail"], r.text

        # the WebSocket: JSON frames, a bad frame (named, skipped), a binary (4, 6) message
        from websockets.sync.client import connect

        ws_url = base.replace("http", "ws") + "/sessions/walk/senses/imu/stream"
        stream = imu_window(8, 4.0, 3)
        with connect(ws_url + "?window=4&stride=4&hz=10&t0=100", open_timeout=30) as ws:
            ready = json.loads(ws.recv(timeout=30))
            assert ready["type"] == "ready" and ready["sense"] == "imu" and ready["shape"] == [6]
            for i, frame in enumerate(stream[:4]):
                ws.send(json.dumps({"frame": frame.tolist(), "t": 100 + i / 10}))
            ws.send(json.dumps({"frame": [0.0] * 5, "t": 101.0}))
            ws.send(npy(stream[4:]))
            msgs = [json.loads(ws.recv(timeout=60)) for _ in range(3)]
        errors = [m for m in msgs if m["type"] == "error"]
        assert len(errors) == 1 and "(6)" in errors[0]["error"]["detail"], msgs
        streamed = [m for m in msgs if m["type"] == "stored"]
        assert [m["seq"] for m in streamed] == [0, 1], msgs
        assert c.get("/sessions/walk").json()["counts"] == {"imu": 2}

        # found by search: the question's words are what the encoder maps a shaking IMU to
        params: dict[str, Any] = {"q": "shaking hard", "k": 10, "sense": "imu", "group": "window"}
        hits = c.get("/search", params=params).json()["hits"]
        found = [h["id"] for h in hits]
        every_shake = {*shaking, *(m["id"] for m in streamed)}
        assert set(found[: len(every_shake)]) == every_shake, hits
        assert found.index(slow[0]) == len(every_shake)  # the slow turn ranks after them
        # the heat maps: a sense that brings no drawer has no picture, a 422 naming the item
        r = c.get(f"/items/{slow[0]}/touch.png")
        assert r.status_code == 422 and "holds no touch window" in r.json()["detail"], r.text
        rows = {s["name"]: s["rows"] for s in c.get("/senses").json()["senses"]}
    assert rows["imu"] == 5 and set(memory.senses) == {"text", "imu"}
