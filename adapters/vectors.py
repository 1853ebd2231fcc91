"""The vector sense: precomputed embeddings from an encoder that lives elsewhere."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.names import validate_sense_name
from tactus_memory.senses.base import Sense
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space
from tactus_memory.vectors import as_unit_rows


@register("vector")
class VectorSense(Sense):
    """Precomputed embeddings from an encoder that lives elsewhere (e.g. an IMU motion model).

    ``memory.add_sense(VectorSense("motion", dim=384))``; items are (D,) vectors, stored
    normalised. ``space`` names the space the external encoder targets (None: trust the
    caller that it is the memory's space).
    """

    modality = "vector"

    def __init__(
        self,
        name: str,
        dim: int,
        *,
        space: str | None = None,
        encoder: str = "external",
        version: str = "",
        checkpoint_sha256: str = "",
    ) -> None:
        self.name = validate_sense_name(name)
        if not isinstance(dim, int) or dim <= 0:
            raise InvalidInputError(f"dim must be a positive int, got {dim!r}")
        self.dim = dim
        self.space_name = space
        self._provenance = {
            "encoder": encoder,
            "version": version,
            "checkpoint_sha256": checkpoint_sha256,
        }

    @classmethod
    def create(cls, space: Space, /, **config: Any) -> VectorSense:
        return cls(**config)

    def config(self) -> dict[str, Any]:
        return {"name": self.name, "dim": self.dim, "space": self.space_name, **self._provenance}

    def validate(self, item: Any) -> np.ndarray:
        return as_unit_rows(item, self.dim, what=f"{self.name} vector")[0]

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        return as_unit_rows(np.stack(list(batch)), self.dim, what=f"{self.name} vector")

    def provenance(self) -> dict[str, Any]:
        return dict(self._provenance)
