"""The text sense: notes and captions, embedded by the space's text model."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tactus_memory.adapters.decode import STRING
from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_TEXT_CHARS
from tactus_memory.names import validate_sense_name
from tactus_memory.senses.base import Sense
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space
from tactus_memory.spaces.figures import calibration_prior, match_precision
from tactus_memory.vectors import as_unit_rows


@register("text")
class TextSense(Sense):
    """Notes and captions, embedded by the space's text model (document side)."""

    modality = "text"

    def __init__(self, space: Space, name: str = "text") -> None:
        self.name = validate_sense_name(name)
        self.space = space
        self.dim = space.dim
        self.space_name = space.name

    message_types = (STRING,)

    def from_message(self, msg: Any, msgtype: str, where: str) -> str:
        return str(msg.data)

    def validate(self, item: Any) -> str:
        if not isinstance(item, str):
            raise InvalidInputError(f"text sense takes a string, got {type(item).__name__}")
        if not item.strip():
            raise InvalidInputError("text is empty")
        if len(item) > MAX_TEXT_CHARS:
            raise InvalidInputError(f"text has {len(item)} characters, limit {MAX_TEXT_CHARS}")
        return item

    def embed(self, batch: Sequence[str]) -> np.ndarray:
        return as_unit_rows(self.space.embed_texts(list(batch), query=False), self.dim)

    def to_row(self, item: str) -> dict[str, Any]:
        return {"text": item}

    def calibration_prior(self) -> dict[str, float] | None:
        """The prior score calibration (``{"mu", "sigma"}``) shipped for text in this sense's
        space (:mod:`tactus_memory.spaces.figures`); None when none is shipped for it."""
        return calibration_prior(str(self.space_name), self.modality)

    def match_precision(self) -> dict[str, Any] | None:
        """How often a text match is right at the text bar in this space, as measured
        (``GET /senses``' ``precision_at_bar``); None when none was measured for it."""
        return match_precision(str(self.space_name), self.modality)

    def provenance(self) -> dict[str, Any]:
        return {"encoder": "space-text", "space": self.space.describe()}
