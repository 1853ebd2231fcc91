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

**Contact and idle.** Every window carries ``contact`` (Wn,): the most taxels at or above
:data:`CONTACT_LEVEL` (calibrated) in any one of its frames. A window whose ``contact`` is below
:data:`CONTACT_MIN_TAXELS` is *idle*: the hand touched nothing worth naming. Decision: idle
windows are **not embedded as grasps**. The rule belongs to the touch sense: its ``validate``
refuses an idle window (:func:`window_idle` on the window it calibrated with its own profile;
``IdleWindowError``) unless asked to keep it, so every way in (HTTP, the WebSocket stream,
recordings, Python) stores the same windows, and an idle hand can never match "holding a ..."
(the stream evaluation, ``tactus eval --stream``, measures how often idle windows pass the
match bar when they *are* embedded: that is the failure this rule removes). Windowing itself
computes ``contact`` only when given a ``profile`` (the evaluation, contact-aware selection);
the service and recording ingest cut windows without it, so frames are calibrated once, by the
sense.

**Contact-aware frame selection.** With ``span > window`` a window is cut from ``span``
consecutive frames and keeps the ``window`` frames with the most contact (ties: earliest), in
time order; its time span covers the whole ``span``. This is the stream-side counterpart of the
paper's cluster-sampled tuples (distinct, informative frames instead of K near-duplicates);
``span == window`` (the default) is plain consecutive windowing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile

#: calibrated level a taxel must reach to count as touching: 1/6 = raw 525 on the STAG glove,
#: ~10 raw above its resting pedestal (stag-format.md "The sensor": rest 510-516). Measured on
#: the real files: the blindfolded subset's labelled grasp frames have a median of 8 taxels at
#: this level, its unlabelled frames a median of 0, the weights subset's empty hand at most 3
#: (95th percentile 2.8).
CONTACT_LEVEL = 1.0 / 6.0
#: a window is idle when none of its frames has this many taxels at CONTACT_LEVEL
CONTACT_MIN_TAXELS = 2
#: a sensor's own contact level is this quantile, over its labelled (grasp) frames, of each
#: frame's CONTACT_MIN_TAXELS-th highest calibrated taxel (:func:`estimate_contact_level`):
#: on the glove's labelled frames (weights_lite + blindfolded_lite_train, 2,561) that quantile
#: is 0.167, the glove's measured CONTACT_LEVEL (1/6), so the rule reproduces it
CONTACT_QUANTILE = 0.10


@dataclass(frozen=True)
class Windows:
    """``frames`` (Wn, K, H, W); ``t``/``t_end`` (Wn,) float64 span of each window;
    ``start`` (Wn,) int64 index of each window's first frame in the run; ``contact`` (Wn,)
    int64 peak contact taxels per window (see the module docstring), None when cut without a
    profile."""

    frames: np.ndarray
    t: np.ndarray
    t_end: np.ndarray
    start: np.ndarray
    contact: np.ndarray | None

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    @property
    def idle(self) -> np.ndarray:
        """(Wn,) bool: windows with no contact (never embedded as grasps)."""
        if self.contact is None:
            raise ValueError("these windows were cut without a profile: contact is unknown")
        return self.contact < CONTACT_MIN_TAXELS

    def take(self, mask: np.ndarray) -> Windows:
        """The windows where ``mask`` (Wn,) bool is True."""
        m = np.asarray(mask, dtype=bool)
        contact = None if self.contact is None else self.contact[m]
        return Windows(self.frames[m], self.t[m], self.t_end[m], self.start[m], contact)


def calibrated_frames(frames: np.ndarray, profile: SensorProfile = STAG_GLOVE) -> np.ndarray:
    """(..., H, W) raw or calibrated -> calibrated float32. Float arrays all in [0, 1] are
    taken as calibrated (the touch sense's auto rule); anything else is raw for ``profile``."""
    arr = np.asarray(frames)
    if arr.size == 0 or (
        np.issubdtype(arr.dtype, np.floating) and arr.min() >= 0 and arr.max() <= 1
    ):
        return arr.astype(np.float32, copy=False)
    return profile.scale(arr)  # no frame-shape check: windowing takes any H x W


def contact_level(profile: SensorProfile | None = None) -> float:
    """The calibrated level at which a taxel of ``profile``'s sensor counts as touching: the
    profile's own ``contact_level`` when it sets one (a checkpoint records it, a sensor file
    may set it), else the glove's :data:`CONTACT_LEVEL`. The one place the level is read."""
    if profile is None or profile.contact_level is None:
        return CONTACT_LEVEL
    return float(profile.contact_level)


def estimate_contact_level(labelled: np.ndarray) -> float:
    """(N, H, W) calibrated labelled (grasp) frames of one sensor -> its contact level: the
    :data:`CONTACT_QUANTILE` quantile of each frame's :data:`CONTACT_MIN_TAXELS`-th highest
    taxel (so that share of grasp frames has fewer taxels in contact), kept inside (0, 1)."""
    frames = np.asarray(labelled, np.float32)
    if frames.ndim != 3 or len(frames) == 0:
        raise InvalidInputError(f"need (N, H, W) labelled frames, got shape {frames.shape}")
    flat = frames.reshape(len(frames), -1)
    kth = np.partition(flat, flat.shape[1] - CONTACT_MIN_TAXELS, axis=1)[:, -CONTACT_MIN_TAXELS]
    return float(np.clip(np.quantile(kth, CONTACT_QUANTILE), 1e-3, 1.0 - 1e-3))


def contact_taxels(frames: np.ndarray, profile: SensorProfile = STAG_GLOVE) -> np.ndarray:
    """(..., H, W) frames -> (...) int64 taxels at or above ``contact_level(profile)``."""
    cal = calibrated_frames(frames, profile)
    return (cal >= np.float32(contact_level(profile))).sum(axis=(-2, -1)).astype(np.int64)


def window_idle(calibrated: np.ndarray, level: float = CONTACT_LEVEL) -> bool:
    """Whether a calibrated window (K, H, W) in [0, 1] is idle: no frame has
    :data:`CONTACT_MIN_TAXELS` taxels at ``level`` (default :data:`CONTACT_LEVEL`; a sensor's
    own: :func:`contact_level`; no calibration here)."""
    peak = (np.asarray(calibrated) >= np.float32(level)).sum(axis=(-2, -1)).max()
    return int(peak) < CONTACT_MIN_TAXELS


def _select(spans: np.ndarray, counts: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """spans (Wn, S, H, W), counts (Wn, S) -> the K most-contact frames of each span in time
    order (Wn, K, H, W), and their counts (Wn, K)."""
    s = spans.shape[1]
    if s == k:
        return spans, counts
    # stable sort on -count keeps the earliest of tied frames
    order = np.argsort(-counts, axis=1, kind="stable")[:, :k]
    order.sort(axis=1)
    rows = np.arange(spans.shape[0])[:, None]
    return spans[rows, order], counts[rows, order]


def _check(window: int, stride: int, span: int | None = None) -> tuple[int, int, int]:
    span = window if span is None else span
    for name, v in (("window", window), ("stride", stride), ("span", span)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InvalidInputError(f"{name} must be a positive int, got {v!r}")
    if span < window:
        raise InvalidInputError(f"span ({span}) must be >= window ({window})")
    return int(window), int(stride), int(span)


def _empty(shape: tuple[int, ...], k: int, dtype: np.dtype) -> Windows:
    z = np.zeros(0, np.float64)
    i = np.zeros(0, np.int64)
    return Windows(np.zeros((0, k, *shape), dtype), z, z.copy(), i, i.copy())


def cut_windows(
    frames: np.ndarray,
    times: Sequence[float] | np.ndarray,
    *,
    window: int,
    stride: int,
    span: int | None = None,
    profile: SensorProfile | None = STAG_GLOVE,
) -> Windows:
    """frames (N, H, W) + times (N,) -> :class:`Windows` (Wn, K, H, W), K = ``window``.

    Each window is cut from ``span`` (default K) consecutive frames starting every ``stride``
    frames; with ``span > K`` it keeps the K frames with the most contact. Wn = 0 when N < span,
    else ``(N - span) // stride + 1``. ``times`` must be as long as ``frames``. ``profile``
    calibrates raw frames for the contact count only (the frames are returned as given); None
    skips the count (``contact`` None; ``span`` must equal ``window`` then).
    """
    k, s, span = _check(window, stride, span)
    if profile is None and span != k:
        raise InvalidInputError("contact-aware selection (span > window) needs a profile")
    arr = np.asarray(frames)
    if arr.ndim != 3:
        raise InvalidInputError(f"frames must be (N, H, W), got shape {arr.shape}")
    ts = np.asarray(times, dtype=np.float64).reshape(-1)
    if ts.shape[0] != arr.shape[0]:
        raise InvalidInputError(f"{ts.shape[0]} times for {arr.shape[0]} frames")
    n = arr.shape[0]
    if n < span:
        return _empty(arr.shape[1:], k, arr.dtype)
    starts = np.arange(0, n - span + 1, s, dtype=np.int64)
    idx = starts[:, None] + np.arange(span, dtype=np.int64)[None, :]  # (Wn, span)
    if profile is None:
        return Windows(arr[idx], ts[starts], ts[starts + span - 1], starts, None)
    counts = contact_taxels(arr, profile)[idx]  # (Wn, span)
    frames_out, kept = _select(arr[idx], counts, k)
    return Windows(frames_out, ts[starts], ts[starts + span - 1], starts, kept.max(axis=1))


class WindowStream:
    """Incremental :func:`cut_windows`: ``push`` frames as they come, get the windows that
    completed (``start`` counts frames since the stream began)."""

    def __init__(
        self,
        window: int,
        stride: int,
        *,
        span: int | None = None,
        profile: SensorProfile | None = STAG_GLOVE,
    ) -> None:
        self.window, self.stride, self.span = _check(window, stride, span)
        self.profile = profile
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
        out = cut_windows(
            arr, ts, window=self.window, stride=self.stride, span=self.span, profile=self.profile
        )
        consumed = len(out) * self.stride  # the next window starts here
        keep_from = min(consumed, arr.shape[0])
        self._skip += consumed - keep_from
        self._frames, self._times = arr[keep_from:], ts[keep_from:]
        starts = out.start + self._offset
        self._offset += keep_from
        return Windows(out.frames, out.t, out.t_end, starts, out.contact)
