"""Named pads of a sensor laid out in one frame: a robot hand's fingertip pads and palm become
one (H, W) frame, so a grasp is one window whatever the hand.

A :class:`Pad` is a named ``rows x cols`` block whose top-left taxel sits at ``(top, left)`` of
the frame. :func:`assemble` places a dict of pad readings into one frame (pixels no pad covers
get ``fill``: the sensor's rest reading, so they calibrate to 0); :func:`split` cuts a frame back
into its pads (for drawing each pad at its place). Both work on raw and calibrated arrays alike
and keep leading axes: ``(..., rows, cols)`` per pad <-> ``(..., H, W)`` frames.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.errors import InvalidInputError


@dataclass(frozen=True)
class Pad:
    """One named block of taxels: ``rows x cols`` taxels, top-left at frame ``(top, left)``."""

    name: str
    rows: int
    cols: int
    top: int
    left: int

    def __post_init__(self) -> None:
        if not self.name or self.rows < 1 or self.cols < 1 or self.top < 0 or self.left < 0:
            raise InvalidInputError(
                f"pad {self.name!r}: needs a name, rows, cols >= 1 and top, left >= 0, "
                f"got {self.rows}x{self.cols} at ({self.top}, {self.left})"
            )

    @property
    def bottom(self) -> int:
        return self.top + self.rows

    @property
    def right(self) -> int:
        return self.left + self.cols

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "shape": [self.rows, self.cols], "at": [self.top, self.left]}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> Pad:
        try:
            rows, cols = (int(v) for v in d["shape"])  # type: ignore[attr-defined]
            top, left = (int(v) for v in d["at"])  # type: ignore[attr-defined]
            return cls(str(d["name"]), rows, cols, top, left)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"a pad needs name, shape = [rows, cols] and at = [top, left], got {dict(d)!r}"
            ) from exc


def check_layout(pads: Sequence[Pad], shape: tuple[int, int]) -> None:
    """Raise :class:`InvalidInputError` when a pad leaves the (H, W) frame, two pads share a
    name, or two pads overlap."""
    h, w = shape
    names = [p.name for p in pads]
    if len(set(names)) != len(names):
        raise InvalidInputError(f"pad names must be unique, got {names}")
    cover = np.zeros(shape, dtype=np.int32)
    for p in pads:
        if p.bottom > h or p.right > w:
            raise InvalidInputError(
                f"pad {p.name!r} ({p.rows}x{p.cols} at ({p.top}, {p.left})) leaves the "
                f"{h}x{w} frame"
            )
        cover[p.top : p.bottom, p.left : p.right] += 1
    if (cover > 1).any():
        r, c = np.argwhere(cover > 1)[0]
        raise InvalidInputError(f"pads overlap at taxel ({r}, {c})")


def layout_extent(pads: Sequence[Pad]) -> tuple[int, int]:
    """The smallest (H, W) frame holding every pad."""
    return max(p.bottom for p in pads), max(p.right for p in pads)


def layout_mask(pads: Sequence[Pad], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the taxels some pad covers."""
    m = np.zeros(shape, dtype=bool)
    for p in pads:
        m[p.top : p.bottom, p.left : p.right] = True
    return m


def assemble(
    readings: Mapping[str, np.ndarray],
    pads: Sequence[Pad],
    shape: tuple[int, int],
    fill: float = 0.0,
) -> np.ndarray:
    """``{pad name: (..., rows, cols)}`` -> (..., H, W) frames, ``fill`` where no pad is.

    Every pad of the layout must be given, with the same leading axes; an unknown name or a
    wrong pad shape raises :class:`InvalidInputError` naming the pad and both shapes."""
    by_name = {p.name: p for p in pads}
    unknown = sorted(set(readings) - set(by_name))
    missing = sorted(set(by_name) - set(readings))
    if unknown or missing:
        raise InvalidInputError(
            f"pad readings must name every pad of the layout {sorted(by_name)}: "
            f"missing {missing}, unknown {unknown}"
        )
    arrays = {k: np.asarray(v) for k, v in readings.items()}
    lead = {a.shape[:-2] for a in arrays.values()}
    if len(lead) != 1 or any(a.ndim < 2 for a in arrays.values()):
        raise InvalidInputError(
            f"pad readings must share their leading axes, got shapes "
            f"{ {k: a.shape for k, a in arrays.items()} }"
        )
    dtype = np.result_type(*arrays.values(), np.asarray(fill).dtype)
    out = np.full((*lead.pop(), *shape), fill, dtype=dtype)
    for name, arr in arrays.items():
        p = by_name[name]
        if arr.shape[-2:] != (p.rows, p.cols):
            raise InvalidInputError(
                f"pad {name!r} is {p.rows}x{p.cols}, got readings of shape {arr.shape}"
            )
        out[..., p.top : p.bottom, p.left : p.right] = arr
    return out


def split(frames: np.ndarray, pads: Sequence[Pad]) -> dict[str, np.ndarray]:
    """(..., H, W) frames -> ``{pad name: (..., rows, cols)}`` (copies), the inverse of
    :func:`assemble` on the pads' taxels."""
    arr = np.asarray(frames)
    if arr.ndim < 2:
        raise InvalidInputError(f"expected (..., H, W) frames, got shape {arr.shape}")
    h, w = arr.shape[-2:]
    if pads and (max(p.bottom for p in pads) > h or max(p.right for p in pads) > w):
        raise InvalidInputError(f"the pad layout does not fit {h}x{w} frames")
    return {p.name: arr[..., p.top : p.bottom, p.left : p.right].copy() for p in pads}
