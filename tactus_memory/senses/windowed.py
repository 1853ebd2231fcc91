"""The windowed-sense contract: a sense whose items are windows cut from a stream of frames
(touch: (K, H, W) windows of (H, W) pressure frames; an IMU would be (K, C)).

What a windowed sense says about itself, so the code that feeds it (recordings, and the
service's windowed routes) needs none of the sense's own modules:

- ``frame_shape``: the shape of one frame (``(32, 32)`` for the STAG glove);
- ``parse_window``: one posted or recorded window -> a ``(K, *frame_shape)`` float array, or
  :class:`~tactus_memory.errors.InvalidInputError` naming what is wrong (shape, values);
- ``is_idle``: the idle rule (a window nobody touched is skipped, never stored);
- ``window_stream``: the cutter of one stream of frames into windows (``push(frames,
  times)`` returns the windows completed; ``pending`` counts the frames waiting); by default
  :class:`FrameStream`, which cuts frames of any shape;
- ``drawer``: how its windows are drawn as a picture (a :class:`WindowDrawer`: a PNG and the
  numbers behind it), or None for a sense that draws none; ``drawer_from_provenance`` builds
  one for a sense known from the store only.

The service reads windowed senses through this contract alone (``service/touch_senses.py``:
the write routes, the WebSocket stream, search by example, the heat maps): a new windowed
sense (an IMU, a force-torque sensor) is served over HTTP and the WebSocket by one
``memory.add_sense(...)`` (``tests/service/test_windowed_sense.py``).

``Sense.windowed`` is True exactly for the subclasses of :class:`WindowedSense`.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, TypedDict

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.senses.base import Sense


class WindowCutter(Protocol):
    """One stream's cutter: frames in, the windows they complete out."""

    @property
    def pending(self) -> int:
        """Frames received that no completed window holds yet."""
        ...

    def push(self, frames: np.ndarray, times: Sequence[float] | np.ndarray) -> Any:
        """``frames`` (n, *frame_shape) at ``times`` (n,) -> the windows completed
        (``len()`` of them; ``.frames[i]`` one window, ``(K, *frame_shape)``)."""
        ...


@dataclass(frozen=True)
class CutWindows:
    """The windows one push completed: ``frames`` (Wn, K, *frame_shape); ``t``/``t_end``
    (Wn,) float64, the times of each window's first and last frame."""

    frames: np.ndarray
    t: np.ndarray
    t_end: np.ndarray

    def __len__(self) -> int:
        return int(self.frames.shape[0])


class FrameStream:
    """The default :class:`WindowCutter`: windows of ``window`` consecutive frames every
    ``stride`` frames (``stride > window`` skips frames), frames of any shape, as given."""

    def __init__(self, window: int, stride: int) -> None:
        if window < 1 or stride < 1:
            raise InvalidInputError(f"window and stride must be >= 1, got {window} and {stride}")
        self.window, self.stride = int(window), int(stride)
        self._frames: np.ndarray | None = None  # (n, *frame_shape) buffered
        self._times = np.zeros(0, np.float64)
        self._skip = 0  # frames still to drop before the next window starts

    @property
    def pending(self) -> int:
        return 0 if self._frames is None else int(self._frames.shape[0])

    def push(self, frames: np.ndarray, times: Sequence[float] | np.ndarray) -> CutWindows:
        arr = np.asarray(frames)
        ts = np.asarray(times, dtype=np.float64).reshape(-1)
        if arr.ndim < 1 or ts.shape[0] != arr.shape[0]:
            raise InvalidInputError(f"push (n, ...) frames with n times; got {arr.shape}")
        drop = min(self._skip, arr.shape[0])
        arr, ts, self._skip = arr[drop:], ts[drop:], self._skip - drop
        if self._frames is not None and len(self._frames):
            if arr.shape[1:] != self._frames.shape[1:]:
                raise InvalidInputError(
                    f"frame shape changed from {self._frames.shape[1:]} to {arr.shape[1:]}"
                )
            arr, ts = np.concatenate([self._frames, arr]), np.concatenate([self._times, ts])
        n, k = arr.shape[0], self.window
        starts = np.arange(0, max(n - k + 1, 0), self.stride, dtype=np.int64)  # (Wn,)
        idx = starts[:, None] + np.arange(k, dtype=np.int64)[None, :]  # (Wn, K)
        out = CutWindows(arr[idx], ts[starts], ts[starts + k - 1])
        consumed = len(starts) * self.stride  # where the next window starts
        keep = min(consumed, n)
        self._skip += consumed - keep
        self._frames, self._times = arr[keep:], ts[keep:]
        return out


class WindowLayout(TypedDict, total=False):
    """How a request asks a window to be drawn: ``scale`` (pixels per cell), ``max_frames``
    (most frames drawn, evenly spread), ``columns`` (frames per row; None: one row),
    ``outline`` (the sensor's parts outlined where the sense knows them: a hand's regions or
    pads)."""

    scale: int
    max_frames: int
    columns: int | None
    outline: bool


class WindowDrawer(Protocol):
    """How one windowed sense's windows are drawn (the service's heat maps)."""

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """The shape of the frames it draws."""
        ...

    def png(
        self, window: np.ndarray, *, calibrated: bool | None, legend: bool, layout: WindowLayout
    ) -> bytes:
        """``window`` (K, *frame_shape), raw or calibrated (None: decided from the values) ->
        PNG bytes."""
        ...

    def values(
        self, window: np.ndarray, *, calibrated: bool | None, layout: WindowLayout
    ) -> dict[str, Any]:
        """The numbers behind :meth:`png` (JSON-ready)."""
        ...


class WindowedSense(Sense):
    """A sense whose items are windows of frames (see the module)."""

    windowed = True
    #: the layout a picture of its windows has when a request asks for none
    draw_defaults: ClassVar[WindowLayout] = {}
    #: the frame shape of the class's default model (a sense's own ``frame_shape`` may differ:
    #: a touch checkpoint of another sensor); () where the class has none
    default_frame_shape: ClassVar[tuple[int, ...]] = ()

    @property
    @abstractmethod
    def frame_shape(self) -> tuple[int, ...]:
        """The shape of one frame."""

    def window_stream(self, window: int, stride: int) -> WindowCutter:
        """A cutter for one stream of raw frames: windows of ``window`` frames every
        ``stride`` frames (:class:`FrameStream`; a sense may cut its own way)."""
        return FrameStream(window, stride)

    def drawer(self) -> WindowDrawer | None:
        """How this sense's windows are drawn; None: it draws none."""
        return None

    @classmethod
    def drawer_from_provenance(cls, provenance: dict[str, Any]) -> WindowDrawer | None:
        """How the windows of a sense of this class known only from the store (``provenance``
        as recorded) are drawn; None: they are not."""
        return None

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


def described_shape(live: Sense | None, provenance: dict[str, Any]) -> list[int] | None:
    """The frame shape ``GET /senses`` states for a sense: a live windowed sense's
    ``frame_shape``; for one known from the store, the sensor profile its provenance records
    (``calibration.shape``, a touch sense's); None for a sense that is not windowed."""
    if isinstance(live, WindowedSense):
        return [int(n) for n in live.frame_shape]
    recorded = provenance.get("calibration")
    if isinstance(recorded, dict) and "shape" in recorded:
        return [int(n) for n in recorded["shape"]]
    return None
