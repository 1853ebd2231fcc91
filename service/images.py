"""Images over HTTP: decoding uploads (with limits) and encoding stored thumbnails as PNG.

Shared by ``POST /sessions/{id}/image``, ``POST /search/like/image`` and
``GET /items/{id}/image.png``. Every bad upload is an ``InvalidInputError`` (422) naming the
problem; bodies beyond ``max_body_bytes`` never get here (413 from the middleware).
"""

from __future__ import annotations

import io
import warnings
from typing import Any

import numpy as np

from tactus_memory.errors import CapabilityError, InvalidInputError

#: formats accepted on upload (what cameras and browsers produce)
IMAGE_FORMATS = ("PNG", "JPEG", "WEBP")
#: most pixels decoded (8000 x 8000): beyond it the upload is refused before decoding
MAX_IMAGE_PIXELS = 64_000_000
#: the shortest side accepted (Qwen3-VL patches are 16 px; a sliver embeds nothing useful)
MIN_IMAGE_SIDE = 8
#: the longest/shortest side ratio accepted (Qwen2-VL's smart_resize refuses beyond 200)
MAX_ASPECT = 200


def decode_image(raw: bytes) -> np.ndarray:
    """PNG/JPEG/WebP bytes -> (H, W, 3) uint8 RGB. Raises InvalidInputError naming why not."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - pillow ships with the vision extra
        raise CapabilityError("image upload needs Pillow (pip install pillow)") from None
    if not raw:
        raise InvalidInputError("the image file is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(raw))
            fmt = img.format
            if fmt not in IMAGE_FORMATS:
                accepted = ", ".join(IMAGE_FORMATS)
                raise InvalidInputError(
                    f"image format {fmt or 'unknown'} is not accepted; send {accepted}"
                )
            w, h = img.size
            if w * h > MAX_IMAGE_PIXELS:
                raise InvalidInputError(
                    f"image is {w}x{h} = {w * h} pixels; limit {MAX_IMAGE_PIXELS}"
                )
            arr = np.asarray(img.convert("RGB"), dtype=np.uint8)
    except InvalidInputError:
        raise
    except Exception as exc:  # noqa: BLE001  (PIL raises many kinds on garbage)
        raise InvalidInputError(f"file is not a readable PNG/JPEG/WebP image: {exc}") from None
    h, w = arr.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise InvalidInputError(f"image is {w}x{h}; each side must be >= {MIN_IMAGE_SIDE} px")
    if max(h, w) > MAX_ASPECT * min(h, w):
        raise InvalidInputError(f"image is {w}x{h}; the aspect ratio must be <= {MAX_ASPECT}")
    return arr


def encode_png(image: Any, side: int | None = None) -> bytes:
    """(H, W, 3) uint8 -> PNG bytes, shrunk so its longest side is <= ``side`` when given."""
    from PIL import Image

    from tactus_memory.adapters.image import thumbnail

    arr = np.asarray(image)
    if side is not None:
        arr = thumbnail(arr, side)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(arr)).save(buf, format="PNG", optimize=False)
    return buf.getvalue()


def is_image_array(value: Any) -> bool:
    return (
        isinstance(value, np.ndarray)
        and value.ndim == 3
        and value.shape[2] == 3
        and value.dtype == np.uint8
    )
