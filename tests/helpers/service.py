"""Helpers for the service tests: a stand-in touch sense and app/memory builders (no tests)."""

from __future__ import annotations

import io
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.adapters.decode import ARRAYS, IMAGE, touch_frame
from tactus_memory.errors import IdleWindowError, InvalidInputError
from tactus_memory.senses.base import array_to_bytes
from tactus_memory.senses.windowed import WindowedSense
from tactus_memory.touch.profile import FRAME_SHAPE
from tactus_memory.touch.windows import WindowStream, calibrated_frames, window_idle
from tactus_memory.vectors import as_unit_rows


class StandInTouch(WindowedSense):
    """A touch sense for tests: a fixed random projection of the flattened window mean."""

    modality = "touch"
    message_types = (IMAGE, *ARRAYS)  # reads recorded touch topics as the touch sense does
    frame_shape = FRAME_SHAPE
    validate_options = frozenset({"keep_idle"})

    def __init__(self, dim: int, name: str = "touch", seed: int = 0) -> None:
        self.name = name
        self.dim = dim
        rng = np.random.default_rng(seed)
        self.proj = rng.standard_normal((32 * 32, dim)).astype(np.float32)

    def from_message(self, msg: Any, msgtype: str, where: str) -> np.ndarray:
        return touch_frame(msg, msgtype, FRAME_SHAPE, where)

    def window_stream(self, window: int, stride: int) -> WindowStream:
        return WindowStream(window, stride, profile=None)  # raw windows, as the touch sense

    def is_idle(self, window: np.ndarray) -> bool:
        return window_idle(calibrated_frames(window))  # the touch sense's rule

    def validate(self, item: Any, *, keep_idle: bool = False) -> np.ndarray:
        arr = np.asarray(item, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[1:] != (32, 32):
            raise InvalidInputError(f"touch window has shape {arr.shape}, expected (K, 32, 32)")
        if not np.isfinite(arr).all():
            raise InvalidInputError("touch window contains NaN or inf")
        if not keep_idle and self.is_idle(arr):
            raise IdleWindowError("idle touch window: no contact")
        return arr

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        flat = np.stack([w.mean(axis=0).reshape(-1) for w in batch])
        flat = flat - flat.mean(axis=1, keepdims=True) + 1e-3
        return as_unit_rows(flat @ self.proj, self.dim)

    def to_row(self, item: np.ndarray) -> dict[str, Any]:
        return {"raw": array_to_bytes(item.astype(np.float16))}

    def provenance(self) -> dict[str, Any]:
        return {"encoder": "stand-in-touch", "version": "test"}


def make_memory(path: Path, *, touch: bool = True, dim: int = 64) -> Any:
    from tactus_memory.memory.main import Memory
    from tests.helpers.fakes import HashingSpace

    memory = Memory.open(str(path), space=HashingSpace(dim=dim))
    if touch:
        memory.add_sense(StandInTouch(dim))
    return memory


def window(k: int = 8, seed: int = 0, base: float = 550.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (base + 50 * rng.random((k, 32, 32))).astype(np.float32)


def npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def assert_problem(r: Any, status: int, *words: str) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body = r.json()
    assert body["status"] == status
    assert {"type", "title", "status", "detail"} <= body.keys()
    for word in words:
        assert word.lower() in body["detail"].lower(), body["detail"]
    return body


def touch_json(seed: int = 0, t: float = 1.0, **kw: Any) -> dict[str, Any]:
    return {"frames": window(seed=seed).tolist(), "t": t, **kw}


def windows(n: int, idle: set[int]) -> np.ndarray:
    """(n, 2, 32, 32) raw windows, each pressing a different patch; those in ``idle`` rest."""
    out = np.full((n, 2, 32, 32), REST, np.int16)
    for i in range(n):
        if i not in idle:
            r, c = divmod(i % 49, 7)
            out[i, :, 4 * r : 4 * r + 4, 4 * c : 4 * c + 4] = 600 + i % 40
    return out


class GatedTouch(StandInTouch):
    """Embedding blocks until ``gate`` is set (``entered`` says a commit is under way)."""

    def __init__(self, dim: int) -> None:
        super().__init__(dim)
        self.gate = threading.Event()
        self.entered = threading.Event()

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        self.entered.set()
        assert self.gate.wait(30), "test gate never opened"
        return super().embed(batch)


PROBLEM = "application/problem+json"


REST = 512  # a raw resting reading: no taxel in contact


DIM = 64


FRAMES = 4
