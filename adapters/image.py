"""The image sense: camera frames, embedded by the space's vision tower."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tactus_memory.adapters.decode import COMPRESSED, IMAGE, camera_image
from tactus_memory.errors import CapabilityError, InvalidInputError
from tactus_memory.names import validate_sense_name
from tactus_memory.senses.base import Sense, array_to_bytes
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space
from tactus_memory.vectors import as_unit_rows

#: longest side of the thumbnail an image item keeps in ``raw`` (256 px: <= 192 KiB a row)
THUMBNAIL_SIDE = 256


@register("image")
class ImageSense(Sense):
    """Camera frames, embedded by the space's vision tower (only for spaces with vision)."""

    modality = "image"

    def __init__(self, space: Space, name: str = "image") -> None:
        if not space.has_vision:
            raise CapabilityError(
                f"space {space.name!r} has no vision; an image sense needs a vision space "
                "such as Qwen3VLSpace"
            )
        self.name = validate_sense_name(name)
        self.space = space
        self.dim = space.dim
        self.space_name = space.name

    message_types = (IMAGE, COMPRESSED)

    def from_message(self, msg: Any, msgtype: str, where: str) -> np.ndarray:
        return camera_image(msg, msgtype, where)

    def validate(self, item: Any) -> np.ndarray:
        """(H, W, 3) uint8, or a PIL image of any mode (converted to RGB)."""
        if hasattr(item, "convert") and hasattr(item, "mode"):  # a PIL image
            item = item.convert("RGB")
        arr = np.asarray(item)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise InvalidInputError(f"image must be (H, W, 3) uint8, got {arr.shape} {arr.dtype}")
        return arr

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        return as_unit_rows(self.space.embed_images(list(batch)), self.dim)

    def to_row(self, item: np.ndarray) -> dict[str, Any]:
        """Keep a thumbnail (longest side <= THUMBNAIL_SIDE, (h, w, 3) uint8) for drawing."""
        return {"raw": array_to_bytes(thumbnail(item, THUMBNAIL_SIDE))}

    def provenance(self) -> dict[str, Any]:
        return {"encoder": "space-vision", "space": self.space.describe()}


def thumbnail(image: np.ndarray, side: int) -> np.ndarray:
    """(H, W, 3) uint8 -> (h, w, 3) uint8 with max(h, w) <= side, aspect kept (Lanczos)."""
    h, w = image.shape[:2]
    if max(h, w) <= side:
        return np.ascontiguousarray(image)
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(image))
    img.thumbnail((side, side), Image.Resampling.LANCZOS)
    return np.asarray(img.convert("RGB"), dtype=np.uint8)
