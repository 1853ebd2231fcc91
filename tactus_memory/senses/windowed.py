"""The windowed-sense contract: a sense whose items are windows cut from a stream of frames
(touch: (K, H, W) windows of (H, W) pressure frames; an IMU would be (K, C)).

What a windowed sense says about itself, so the code that feeds it (recordings, and the
service's windowed routes) needs none of the sense's own modules:

- ``frame_shape``: the shape of one frame (``(32, 32)`` for the STAG glove);
- ``parse_window``: one posted or recorded window -> a ``(K, *frame_shape)`` float array, or
  :class:`~tactus_memory.errors.InvalidInputError` naming what is wrong (shape, values);
- ``is_idle``: the idle rule (a window nobody touched is skipped, never stored);
- ``window_stream``: the cutter of one stream of frames into windows (``push(frames,
  times)`` returns the windows completed; ``pending`` counts the frames waiting).

``Sense.windowed`` is True exactly for the subclasses of :class:`WindowedSense`.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.senses.base import Sense


class WindowCutter(Protocol):
    """One stream's cutter: frames in, the windows they complete out."""

    @property
    def pending(self) -> int:
        """Frames received that no completed window holds yet."""
        ...

    def push(self, frames: np.ndarray, times: Sequence[float]) -> Any:
        """``frames`` (n, *frame_shape) at ``times`` (n,) -> the windows completed
        (``len()`` of them; ``.frames[i]`` one window, ``(K, *frame_shape)``)."""
        ...


class WindowedSense(Sense):
    """A sense whose items are windows of frames (see the module)."""

    windowed = True

    @property
    @abstractmethod
    def frame_shape(self) -> tuple[int, ...]:
        """The shape of one frame."""

    @abstractmethod
    def window_stream(self, window: int, stride: int) -> WindowCutter:
        """A cutter for one stream of raw frames: windows of ``window`` frames every
        ``stride`` frames."""

    @abstractmethod
    def is_idle(self, window: np.ndarray) -> bool:
        """Whether the validated ``window`` is idle (no contact): it is skipped, not stored."""

    def parse_window(self, payload: Any) -> np.ndarray:
        """One window as given (nested lists or an array) -> a ``(K, *frame_shape)`` float32
        array of finite values; InvalidInputError names the shape it got and the one it
        needs. (Calibration and the idle rule are ``validate``'s.)"""
        try:
            arr = np.asarray(payload, dtype=np.float32)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"a {self.name} window is numbers: {exc}") from None
        shape = tuple(self.frame_shape)
        if arr.ndim != 1 + len(shape) or tuple(arr.shape[1:]) != shape or arr.shape[0] < 1:
            raise InvalidInputError(
                f"a {self.name} window is (K, {', '.join(map(str, shape))}) frames, "
                f"got shape {tuple(arr.shape)}"
            )
        if not np.isfinite(arr).all():
            raise InvalidInputError(f"a {self.name} window holds NaN or infinite values")
        return arr
