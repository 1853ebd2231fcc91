"""The Space protocol: the frozen embedding model that defines the shared vector space."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np

from tactus_memory.errors import CapabilityError, InvalidInputError


class Space(ABC):
    """A frozen embedding model. A store is bound to exactly one space (``name``, ``dim``).

    Subclasses load lazily: constructing a space is cheap, the model loads on first use.
    """

    #: registry name recorded in the store, e.g. ``"minilm-l6"``
    name: str
    #: embedding dimension D
    dim: int
    #: whether ``embed_images`` works
    has_vision: bool = False
    #: whether the space needs a local model folder (``path``) to be built
    needs_path: bool = False
    #: what ``tactus_memory.senses.plugins.register`` files it under
    plugin_kind = "space"

    @classmethod
    def create(cls, path: str | None = None, dim: int | None = None) -> Space:
        """The space from the user's options (``get_space``): a model folder and a dim.
        ValueError names an option the space cannot take."""
        if dim is not None and dim != cls.dim:
            raise ValueError(f"space {cls.name!r} has dim {cls.dim}; dim={dim} is not possible")
        return cls(path) if path is not None else cls()  # type: ignore[call-arg]  # subclasses take a path

    @abstractmethod
    def embed_texts(self, texts: Sequence[str], *, query: bool = False) -> np.ndarray:
        """texts: N strings -> (N, D) float32, L2-normalised.

        ``query=True`` embeds the query side (spaces with instruction prompts use them here);
        ``query=False`` embeds documents (notes stored in the memory, class phrases).
        """

    def embed_images(self, images: Sequence[Any]) -> np.ndarray:
        """images: N PIL images or (H, W, 3) uint8 arrays -> (N, D) float32, L2-normalised."""
        raise CapabilityError(f"space {self.name!r} has no vision: it cannot embed images")

    def fingerprint(self) -> str | None:
        """Which model files define this space (recorded in a store, checked on reopen);
        None for spaces whose model is fixed by their name (MiniLM ships in a package)."""
        return None

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "dim": self.dim, "has_vision": self.has_vision}


def check_texts(texts: Sequence[str]) -> list[str]:
    """The input check every space's ``embed_texts`` shares: a sequence of strings (not one)."""
    if isinstance(texts, str):
        raise InvalidInputError("embed_texts takes a sequence of strings, not one string")
    items = list(texts)
    for t in items:
        if not isinstance(t, str):
            raise InvalidInputError(f"embed_texts takes strings, got {type(t).__name__}")
    return items
