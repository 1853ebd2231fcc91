"""Touch windows as pressure heat maps of the hand: ONE renderer for the web page and reports.

``draw_window_png(window) -> bytes`` draws a (K, H, W) window as K frames (in a row, or a
grid with ``columns``) with a colour bar under them. Readable for real grasps:

- **scale**: calibrated pressure (``clip((raw - 500) / 150, 0, 1)`` for the STAG glove), shown
  from the contact level ``lo`` (raw 520: the resting pedestal is 510-516, stag-format.md
  "The sensor"; only 3% of the empty hand's readings in the weights subset exceed it) to a
  robust per-window top ``hi`` (the 99th percentile of its taxel readings, at least
  ``lo + MIN_RANGE`` so a quiet window's noise is not stretched to full brightness), with a
  gamma of 0.5 so light contact (real grasps mostly sit below 0.3) is visible next to firm
  contact. The colour bar states ``lo``, ``hi`` and the gamma in calibrated units.
- **colour**: matplotlib's perceptual ``magma``; a taxel at or below ``lo`` is magma's darkest
  colour, so only contact lights up.
- **any sensor**: a frame is the profile's H x W grid (``SensorProfile.shape``: 32x32 for the
  STAG glove, 16x16 for a skin, a robot hand's pads assembled into one frame).
- **unused taxels** (the 476 pixels of the 32x32 raster that are not taxels of the glove,
  ``data.taxel_mask_from_spec``; for another sensor the pixels outside its taxel mask, e.g.
  the gaps between a hand's pads, :func:`profile_mask`) are drawn in the background colour,
  a near-black slate a shade lighter than "no contact": the sensor layout shows faintly, never
  as bright bars. Frames are separated by grey lines.

:func:`window_values` gives the same window as numbers (calibrated values, the taxel mask,
the scale and the layout) so the page can show the value under the pointer. Used by the
service (``GET /items/{id}/touch.png`` and ``/touch.json``) and the ``tactus eval`` report.
"""

from __future__ import annotations

import io
from dataclasses import asdict, dataclass
from typing import Any, TypedDict

import numpy as np
from typing_extensions import Unpack

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import (
    FRAME_SHAPE,
    STAG_GLOVE,
    SensorProfile,
    taxel_mask_from_spec,
)

#: default pixels per taxel: a glove frame is 32*4 = 128 px square
SCALE = 4
#: most frames drawn; longer windows are subsampled evenly (first and last kept)
MAX_FRAMES = 16
#: background pixels between frames, in taxels
GAP = 1
COLORMAP = "magma"
#: display gamma: value shown = ((cal - lo) / (hi - lo)) ** GAMMA
GAMMA = 0.5
#: contact starts this many raw units above the profile's resting reading (STAG: 512 + 8 = 520;
#: the pedestal is 510-516 raw, stag-format.md; 97% of empty-hand readings stay at or below 520)
CONTACT_MARGIN_RAW = 8.0
#: calibrated contact level when the profile names no resting reading
CONTACT_FALLBACK = 0.1
#: smallest shown range (calibrated; 15 raw units on the STAG glove)
MIN_RANGE = 0.1
#: top of the per-window range: this percentile of the window's taxel readings
TOP_PERCENTILE = 99.0
#: the unused (non-taxel) pixels and the colour bar's strip, RGBA: a near-black slate, a
#: shade above "no contact" (magma's darkest, (0, 0, 4)), so the sensor layout shows faintly
BACKGROUND = (22, 22, 32, 255)
#: between frames, RGBA: a mid grey that separates them
GAP_COLOUR = (120, 124, 134, 255)
#: height of the colour bar strip, in pixels (bar + labels)
LEGEND_PX = 34
#: the outline between two hand regions or pads (``outline=True``), RGBA: a cyan that the
#: magma colour map never reaches (its hues run black - purple - orange - pale yellow)
OUTLINE_COLOUR = (64, 224, 255, 255)


@dataclass(frozen=True)
class TouchScale:
    """How calibrated pressure maps to colour: ``lo`` (contact level, darkest) to ``hi``
    (brightest), ``gamma`` in between; all values calibrated 0..1."""

    lo: float
    hi: float
    gamma: float = GAMMA
    colormap: str = COLORMAP

    def unit(self, cal: np.ndarray) -> np.ndarray:
        """Calibrated values -> 0..1 colour positions (0 at or below ``lo``)."""
        v = np.clip((np.asarray(cal, np.float32) - self.lo) / (self.hi - self.lo), 0.0, 1.0)
        return v**self.gamma


@dataclass(frozen=True)
class Layout:
    """Where frame ``i`` sits: column ``i % columns``, row ``i // columns``, each frame
    ``frame_cols * scale`` px wide and ``frame_rows * scale`` px high (the sensor's H x W),
    ``gap * scale`` px between frames."""

    frames: int
    columns: int
    scale: int
    gap: int
    frame_rows: int = FRAME_SHAPE[0]
    frame_cols: int = FRAME_SHAPE[1]

    @property
    def rows(self) -> int:
        return -(-self.frames // self.columns)

    @property
    def pitch_x(self) -> int:
        return (self.frame_cols + self.gap) * self.scale

    @property
    def pitch_y(self) -> int:
        return (self.frame_rows + self.gap) * self.scale

    @property
    def width(self) -> int:
        return self.columns * self.pitch_x - self.gap * self.scale

    @property
    def height(self) -> int:
        return self.rows * self.pitch_y - self.gap * self.scale

    def origin(self, i: int) -> tuple[int, int]:
        """(x, y) of frame ``i``'s top-left pixel."""
        return (i % self.columns) * self.pitch_x, (i // self.columns) * self.pitch_y


def profile_mask(profile: SensorProfile) -> np.ndarray:
    """(H, W) bool, the pixels of ``profile``'s frame that are taxels: the profile's own mask
    when it carries one (``taxel_mask``, e.g. a hand's pads placed in one frame), the spec's
    548 taxels for a 32x32 glove frame, else every pixel of the H x W grid."""
    own = getattr(profile, "taxel_mask", None)
    own = own() if callable(own) else own
    if own is not None:
        mask = np.asarray(own, dtype=bool)
        if mask.shape != tuple(profile.shape):
            raise InvalidInputError(
                f"profile {profile.name!r}: taxel mask {mask.shape} is not its frame "
                f"shape {tuple(profile.shape)}"
            )
        return mask
    if tuple(profile.shape) == FRAME_SHAPE:
        return taxel_mask_from_spec()
    return np.ones(profile.shape, dtype=bool)


def as_frames(window: Any, shape: tuple[int, int] = FRAME_SHAPE) -> np.ndarray:
    """(K, H, W) or (H, W) numbers, (H, W) = ``shape`` -> float32 (K, H, W), finite; raises
    otherwise."""
    arr = np.asarray(window)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise InvalidInputError(f"a touch window must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float32)
    if arr.ndim == 2:
        arr = arr[None]
    h, w = shape
    if arr.ndim != 3 or arr.shape[1:] != tuple(shape) or arr.shape[0] == 0:
        raise InvalidInputError(
            f"touch window has shape {arr.shape}, expected (K, {h}, {w}): the sensor's "
            f"frames are {h}x{w}"
        )
    if not np.isfinite(arr).all():
        raise InvalidInputError("touch window contains NaN or inf")
    return arr


def calibrated_frames(
    window: Any, *, calibrated: bool | None = None, profile: SensorProfile = STAG_GLOVE
) -> np.ndarray:
    """The window as calibrated pressure in [0, 1].

    ``calibrated=None`` decides from the values: everything within [0, 1] is already
    calibrated (raw glove units sit near 500-1000 and never are), anything else is raw.
    """
    arr = as_frames(window, tuple(profile.shape))  # type: ignore[arg-type]
    if calibrated is None:
        calibrated = bool(arr.min() >= 0.0 and arr.max() <= 1.0)
    if calibrated:
        return np.clip(arr, 0.0, 1.0)
    return profile.calibrate(arr)


def pick_frames(n: int, max_frames: int = MAX_FRAMES) -> np.ndarray:
    """Indices of at most ``max_frames`` frames of ``n``, evenly spread, first and last kept."""
    if n <= max_frames:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_frames).round().astype(np.int64))


def contact_level(profile: SensorProfile = STAG_GLOVE) -> float:
    """Calibrated level where contact starts (STAG glove: raw 520 -> 0.1333)."""
    if profile.rest_raw is None:
        return CONTACT_FALLBACK
    return float((profile.rest_raw + CONTACT_MARGIN_RAW - profile.offset) / profile.span)


def touch_scale(
    frames: np.ndarray, taxels: np.ndarray, profile: SensorProfile = STAG_GLOVE
) -> TouchScale:
    """The per-window scale: ``lo`` = contact level, ``hi`` = robust top of the window's
    taxel readings (``TOP_PERCENTILE``), at least ``lo + MIN_RANGE``, at most 1 (or ``lo``
    plus a sliver when the contact level itself is near the ceiling)."""
    lo = contact_level(profile)
    top = float(np.percentile(frames[:, taxels], TOP_PERCENTILE)) if taxels.any() else lo
    hi = min(max(top, lo + MIN_RANGE), 1.0)
    return TouchScale(lo=lo, hi=max(hi, lo + 1e-3))


def _prepare(
    window: Any,
    calibrated: bool | None,
    profile: SensorProfile,
    scale: int,
    max_frames: int,
    gap: int,
    columns: int | None,
    mask: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, TouchScale, Layout]:
    if not 1 <= int(scale) <= 32:
        raise InvalidInputError(f"scale must be in [1, 32], got {scale}")
    if int(max_frames) < 1:
        raise InvalidInputError(f"max_frames must be >= 1, got {max_frames}")
    if columns is not None and int(columns) < 1:
        raise InvalidInputError(f"columns must be >= 1, got {columns}")
    frames = calibrated_frames(window, calibrated=calibrated, profile=profile)
    picked = pick_frames(frames.shape[0], int(max_frames))
    frames = frames[picked]
    taxels = profile_mask(profile) if mask is None else np.asarray(mask, dtype=bool)
    if taxels.shape != frames.shape[1:]:
        raise InvalidInputError(f"mask has shape {taxels.shape}, frames {frames.shape[1:]}")
    k, h, w = frames.shape
    cols = k if columns is None else min(int(columns), k)
    layout = Layout(
        frames=k, columns=cols, scale=int(scale), gap=int(gap), frame_rows=h, frame_cols=w
    )
    return frames, picked, taxels, touch_scale(frames, taxels, profile), layout


class View(TypedDict, total=False):
    """How a window is drawn (the keywords of :func:`window_rgba`, :func:`draw_window_png`,
    :func:`window_values`): ``calibrated`` (None: decided from the values), ``profile``
    (default STAG_GLOVE), ``scale`` (px per taxel, default SCALE), ``max_frames`` (default
    MAX_FRAMES), ``columns`` (frames per row; None: one row)."""

    calibrated: bool | None
    profile: SensorProfile
    scale: int
    max_frames: int
    columns: int | None
    outline: bool


def region_edges(index: np.ndarray, scale: int) -> np.ndarray:
    """(H*scale, W*scale) bool: the pixels outlining the regions of a (H, W) region index
    (-1: no region): the last pixel row or column of a taxel whose neighbour below or to
    the right lies in another region (a region's edge against no region included)."""
    idx = np.asarray(index)
    h, w = idx.shape
    out = np.zeros((h * scale, w * scale), bool)
    right = (idx[:, :-1] != idx[:, 1:]) & ((idx[:, :-1] >= 0) | (idx[:, 1:] >= 0))
    for r, c in zip(*np.nonzero(right), strict=True):
        out[r * scale : (r + 1) * scale, (c + 1) * scale - 1] = True
    below = (idx[:-1] != idx[1:]) & ((idx[:-1] >= 0) | (idx[1:] >= 0))
    for r, c in zip(*np.nonzero(below), strict=True):
        out[(r + 1) * scale - 1, c * scale : (c + 1) * scale] = True
    return out


def _outline(view: View, layout: Layout) -> np.ndarray | None:
    """The region-outline pixels of one frame when ``view`` asks for them and its profile
    has regions (its pads, or the glove's derived hand regions); else None."""
    if not view.get("outline"):
        return None
    from tactus_memory.touch.regions import regions_of

    regions = regions_of(view.get("profile", STAG_GLOVE))
    if regions is None or regions.shape != (layout.frame_rows, layout.frame_cols):
        return None
    return region_edges(regions.index, layout.scale)


def _prepare_view(
    window: Any, view: View, gap: int = GAP, mask: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, TouchScale, Layout]:
    return _prepare(
        window,
        view.get("calibrated"),
        view.get("profile", STAG_GLOVE),
        view.get("scale", SCALE),
        view.get("max_frames", MAX_FRAMES),
        gap,
        view.get("columns"),
        mask,
    )


def window_rgba(
    window: Any, *, gap: int = GAP, mask: np.ndarray | None = None, **view: Unpack[View]
) -> np.ndarray:
    """(H, W, 4) uint8, opaque: the frames (one row, or ``columns`` per row) with grey lines
    between them, unused taxels in the background colour. No colour bar."""
    frames, _, taxels, ts, layout = _prepare_view(window, view, gap, mask)
    return _paint(frames, taxels, ts, layout, _outline(view, layout))


def _paint(
    frames: np.ndarray,
    taxels: np.ndarray,
    ts: TouchScale,
    layout: Layout,
    edges: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 4) uint8 of the (K, h, w) calibrated ``frames``; ``edges`` (h*scale, w*scale)
    bool: pixels drawn in ``OUTLINE_COLOUR`` over every frame."""
    from matplotlib import colormaps

    rgba = colormaps[ts.colormap](ts.unit(frames), bytes=True)  # (K, H, W, 4) uint8
    rgba[:, ~taxels] = BACKGROUND
    s = layout.scale
    fh, fw = layout.frame_rows * s, layout.frame_cols * s
    out = np.empty((layout.height, layout.width, 4), np.uint8)
    out[:] = GAP_COLOUR
    for i in range(layout.frames):
        x, y = layout.origin(i)
        big = np.repeat(np.repeat(rgba[i], s, axis=0), s, axis=1)
        if edges is not None:
            big[edges] = OUTLINE_COLOUR
        out[y : y + fh, x : x + fw] = big
    return out


def _font(size: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def legend_rgba(ts: TouchScale, width: int) -> np.ndarray:
    """(LEGEND_PX, width, 4) uint8: the colour bar from ``lo`` to ``hi`` with its labels."""
    from matplotlib import colormaps
    from PIL import Image, ImageDraw

    width = max(int(width), 160)
    img = Image.new("RGBA", (width, LEGEND_PX), BACKGROUND)
    pad = 6
    bar_w = width - 2 * pad
    ramp = colormaps[ts.colormap](np.linspace(0.0, 1.0, bar_w), bytes=True)[None]
    img.paste(Image.fromarray(np.repeat(ramp, 10, axis=0)), (pad, 4))
    draw = ImageDraw.Draw(img)
    font = _font(11)
    ink = (235, 235, 240, 255)
    draw.text((pad, 16), f"<= {ts.lo:.2f}: no contact", fill=ink, font=font)
    right = f">= {ts.hi:.2f}"
    draw.text((pad + bar_w - draw.textlength(right, font=font), 16), right, fill=ink, font=font)
    mid = f"calibrated pressure (0-1), gamma {ts.gamma:g}"
    if width >= 330:
        draw.text(((width - draw.textlength(mid, font=font)) / 2, 16), mid, fill=ink, font=font)
    return np.asarray(img, dtype=np.uint8)


def encode_png(rgba: np.ndarray) -> bytes:
    """(H, W, 4) uint8 -> PNG bytes (Pillow, which matplotlib depends on)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba)).save(buf, format="PNG")
    return buf.getvalue()


def draw_window_png(window: Any, *, legend: bool = True, **view: Unpack[View]) -> bytes:
    """A touch window as a PNG heat map: one ``W*scale`` x ``H*scale`` px image per frame (in
    one row, or ``columns`` per row), and with ``legend`` a colour bar under them.

    ``window``: (K, H, W) (or one (H, W) frame) of the profile's shape, raw sensor units or
    calibrated 0..1
    (``calibrated=None`` decides from the values). See the module docstring for the scale.
    """
    cal, _, taxels, ts, layout = _prepare_view(window, view)
    frames = _paint(cal, taxels, ts, layout, _outline(view, layout))
    if not legend:
        return encode_png(frames)
    bar = legend_rgba(ts, frames.shape[1])
    width = max(frames.shape[1], bar.shape[1])
    out = np.empty((frames.shape[0] + 4 + bar.shape[0], width, 4), np.uint8)
    out[:] = BACKGROUND
    out[: frames.shape[0], : frames.shape[1]] = frames
    out[frames.shape[0] + 4 :, : bar.shape[1]] = bar
    return encode_png(out)


def window_values(window: Any, **view: Unpack[View]) -> dict[str, Any]:
    """The numbers behind :func:`draw_window_png` (JSON-ready): ``values`` (K', H, W)
    calibrated, rounded to 1e-4, of the drawn frames; ``frames`` their indices in the window;
    ``taxels`` the (H, W) mask; ``scale`` (lo, hi, gamma, colormap); ``layout`` (columns,
    scale, gap, frame_rows x frame_cols in taxels) so a pointer position maps to (frame, row,
    column)."""
    frames, picked, taxels, ts, layout = _prepare_view(window, view)
    return {
        "values": np.round(frames, 4).tolist(),
        "frames": picked.tolist(),
        "taxels": taxels.astype(int).tolist(),
        "scale": asdict(ts),
        "layout": {
            "columns": layout.columns,
            "rows": layout.rows,
            "scale": layout.scale,
            "gap": layout.gap,
            "frame_rows": layout.frame_rows,
            "frame_cols": layout.frame_cols,
            "width": layout.width,
            "height": layout.height,
        },
    }
