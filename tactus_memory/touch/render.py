"""Touch windows as pressure heat maps of the hand: ONE renderer for the web page and reports.

``draw_window_png(window) -> bytes`` draws a (K, 32, 32) window as K small images side by side
(one per frame), calibrated pressure 0..1 through a perceptual colour map, and the pixels of
the 32x32 raster that are not taxels of the glove (``data.taxel_mask_from_spec``: 548 of
1024) left transparent, so the hand's outline shows. Raw sensor units are calibrated with the
sensor profile (STAG glove by default); windows already in [0, 1] are taken as calibrated.

Used by the service (``GET /items/{id}/touch.png``) and meant for the ``tactus eval`` report:
the page and the report show the same picture of the same window.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile, taxel_mask_from_spec

#: default pixels per taxel: a frame is 32*4 = 128 px square
SCALE = 4
#: most frames drawn; longer windows are subsampled evenly (first and last kept)
MAX_FRAMES = 16
#: transparent pixels between frames, in taxels
GAP = 1
COLORMAP = "inferno"


def as_frames(window: Any) -> np.ndarray:
    """(K, 32, 32) or (32, 32) numbers -> float32 (K, 32, 32), finite; raises otherwise."""
    arr = np.asarray(window)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise InvalidInputError(f"a touch window must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float32)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (32, 32) or arr.shape[0] == 0:
        raise InvalidInputError(f"touch window has shape {arr.shape}, expected (K, 32, 32)")
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
    arr = as_frames(window)
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


def window_rgba(
    window: Any,
    *,
    calibrated: bool | None = None,
    profile: SensorProfile = STAG_GLOVE,
    scale: int = SCALE,
    max_frames: int = MAX_FRAMES,
    gap: int = GAP,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 4) uint8: the frames side by side, non-taxel pixels transparent."""
    from matplotlib import colormaps

    if not 1 <= int(scale) <= 32:
        raise InvalidInputError(f"scale must be in [1, 32], got {scale}")
    if int(max_frames) < 1:
        raise InvalidInputError(f"max_frames must be >= 1, got {max_frames}")
    frames = calibrated_frames(window, calibrated=calibrated, profile=profile)
    frames = frames[pick_frames(frames.shape[0], int(max_frames))]
    taxels = taxel_mask_from_spec() if mask is None else np.asarray(mask, dtype=bool)
    if taxels.shape != frames.shape[1:]:
        raise InvalidInputError(f"mask has shape {taxels.shape}, frames {frames.shape[1:]}")
    rgba = colormaps[COLORMAP](frames, bytes=True)  # (K, 32, 32, 4) uint8
    rgba[..., 3] = np.where(taxels, 255, 0).astype(np.uint8)
    k, h, w = frames.shape
    out = np.zeros((h, k * w + (k - 1) * gap, 4), np.uint8)
    for i in range(k):
        out[:, i * (w + gap) : i * (w + gap) + w] = rgba[i]
    s = int(scale)
    return np.repeat(np.repeat(out, s, axis=0), s, axis=1)


def encode_png(rgba: np.ndarray) -> bytes:
    """(H, W, 4) uint8 -> PNG bytes (Pillow, which matplotlib depends on)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba)).save(buf, format="PNG")
    return buf.getvalue()


def draw_window_png(
    window: Any,
    *,
    calibrated: bool | None = None,
    profile: SensorProfile = STAG_GLOVE,
    scale: int = SCALE,
    max_frames: int = MAX_FRAMES,
) -> bytes:
    """A touch window as a PNG heat-map strip: one ``32*scale`` px image per frame.

    ``window``: (K, 32, 32) (or one (32, 32) frame), raw sensor units or calibrated 0..1
    (``calibrated=None`` decides from the values). Colour: ``inferno``, 0 (no pressure) dark
    to 1 (the calibrated ceiling) bright; non-taxel pixels transparent.
    """
    return encode_png(
        window_rgba(
            window, calibrated=calibrated, profile=profile, scale=scale, max_frames=max_frames
        )
    )
