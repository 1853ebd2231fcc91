"""Helpers for the service tests: a stand-in touch sense and app/memory builders (no tests)."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.adapters.decode import ARRAYS, IMAGE, touch_frame
from tactus_memory.errors import IdleWindowError, InvalidInputError
from tactus_memory.sense import Sense, array_to_bytes
from tactus_memory.touch.profile import FRAME_SHAPE
from tactus_memory.touch.windows import calibrated_frames, window_idle
from tactus_memory.vectors import as_unit_rows


class StandInTouch(Sense):
    """A touch sense for tests: a fixed random projection of the flattened window mean."""

    modality = "touch"
    message_types = (IMAGE, *ARRAYS)  # reads recorded touch topics as the touch sense does
    windowed = True
    validate_options = frozenset({"keep_idle"})

    def __init__(self, dim: int, name: str = "touch", seed: int = 0) -> None:
        self.name = name
        self.dim = dim
        rng = np.random.default_rng(seed)
        self.proj = rng.standard_normal((32 * 32, dim)).astype(np.float32)

    def from_message(self, msg: Any, msgtype: str, where: str) -> np.ndarray:
        return touch_frame(msg, msgtype, FRAME_SHAPE, where)

    def validate(self, item: Any, *, keep_idle: bool = False) -> np.ndarray:
        arr = np.asarray(item, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[1:] != (32, 32):
            raise InvalidInputError(f"touch window has shape {arr.shape}, expected (K, 32, 32)")
        if not np.isfinite(arr).all():
            raise InvalidInputError("touch window contains NaN or inf")
        if not keep_idle and window_idle(calibrated_frames(arr)):  # the touch sense's rule
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
    from tests.fakes import HashingSpace

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
