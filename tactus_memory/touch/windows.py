"""Stream windowing: a run of touch frames cut into the windows the touch sense embeds.

ONE entry point, :func:`cut_windows`: frames (N, H, W) with their times (N,) in, windows
(Wn, K, H, W) with their time spans out. Window j holds frames ``j*S .. j*S+K-1`` (K =
``window``, S = ``stride``; ``S > K`` skips frames between windows, ``S < K`` overlaps them);
its span runs from its first frame's time to its last frame's. A tail shorter than K is not a
window.

:class:`WindowStream` feeds :func:`cut_windows` incrementally (frames arrive one by one on the
WebSocket stream, in chunks from a recording) and gives exactly the windows that
:func:`cut_windows` would give on the whole run at once. The live stream
(``service/routers/touch_stream.py``) and recording ingest (``tactus_memory.recordings``) both
window through here, so a recording and a live glove are cut the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.errors import InvalidInputError


@dataclass(frozen=True)
class Windows:
    """``frames`` (Wn, K, H, W); ``t``/``t_end`` (Wn,) float64 span of each window;
    ``start`` (Wn,) int64 index of each window's first frame in the run."""

    frames: np.ndarray
    t: np.ndarray
    t_end: np.ndarray
    start: np.ndarray

    def __len__(self) -> int:
        return int(self.frames.shape[0])


def _check(window: int, stride: int) -> tuple[int, int]:
    for name, v in (("window", window), ("stride", stride)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InvalidInputError(f"{name} must be a positive int, got {v!r}")
    return int(window), int(stride)


def _empty(shape: tuple[int, ...], k: int, dtype: np.dtype) -> Windows:
    z = np.zeros(0, np.float64)
    return Windows(np.zeros((0, k, *shape), dtype), z, z.copy(), np.zeros(0, np.int64))


def cut_windows(
    frames: np.ndarray, times: Sequence[float] | np.ndarray, *, window: int, stride: int
) -> Windows:
    """frames (N, H, W) + times (N,) -> :class:`Windows` (Wn, K, H, W), K = ``window``.

    Wn = 0 when N < K, else ``(N - K) // S + 1``. ``times`` must be as long as ``frames``.
    """
    k, s = _check(window, stride)
    arr = np.asarray(frames)
    if arr.ndim != 3:
        raise InvalidInputError(f"frames must be (N, H, W), got shape {arr.shape}")
    ts = np.asarray(times, dtype=np.float64).reshape(-1)
    if ts.shape[0] != arr.shape[0]:
        raise InvalidInputError(f"{ts.shape[0]} times for {arr.shape[0]} frames")
    n = arr.shape[0]
    if n < k:
        return _empty(arr.shape[1:], k, arr.dtype)
    starts = np.arange(0, n - k + 1, s, dtype=np.int64)
    idx = starts[:, None] + np.arange(k, dtype=np.int64)[None, :]  # (Wn, K)
    return Windows(arr[idx], ts[starts], ts[starts + k - 1], starts)


class WindowStream:
    """Incremental :func:`cut_windows`: ``push`` frames as they come, get the windows that
    completed (``start`` counts frames since the stream began)."""

    def __init__(self, window: int, stride: int) -> None:
        self.window, self.stride = _check(window, stride)
        self._frames: np.ndarray | None = None  # (B, H, W) buffered frames
        self._times = np.zeros(0, np.float64)
        self._offset = 0  # stream index of the buffer's first frame
        self._skip = 0  # frames still to drop before the next window starts (stride > window)

    @property
    def pending(self) -> int:
        """Frames buffered towards the next window."""
        return 0 if self._frames is None else int(self._frames.shape[0])

    def push(self, frames: np.ndarray, times: Sequence[float] | np.ndarray) -> Windows:
        """frames (n, H, W) or one frame (H, W) + their times -> the windows completed now."""
        arr = np.asarray(frames)
        if arr.ndim == 2:
            arr = arr[None]
        ts = np.asarray(times, dtype=np.float64).reshape(-1)
        if arr.ndim != 3 or ts.shape[0] != arr.shape[0]:
            raise InvalidInputError(
                f"push frames (n, H, W) with n times; got {arr.shape} and {ts.shape[0]} times"
            )
        if self._skip:
            drop = min(self._skip, arr.shape[0])
            arr, ts = arr[drop:], ts[drop:]
            self._skip -= drop
            self._offset += drop
        if self._frames is not None and self._frames.shape[0]:
            if arr.shape[1:] != self._frames.shape[1:]:
                raise InvalidInputError(
                    f"frame shape changed from {self._frames.shape[1:]} to {arr.shape[1:]}"
                )
            arr = np.concatenate([self._frames, arr])
            ts = np.concatenate([self._times, ts])
        out = cut_windows(arr, ts, window=self.window, stride=self.stride)
        consumed = len(out) * self.stride  # the next window starts here
        keep_from = min(consumed, arr.shape[0])
        self._skip += consumed - keep_from
        self._frames, self._times = arr[keep_from:], ts[keep_from:]
        starts = out.start + self._offset
        self._offset += keep_from
        return Windows(out.frames, out.t, out.t_end, starts)
