"""Embedding spaces. ``get_space(name, path=None)`` builds one by registry name.

Known names: ``"minilm"`` / ``"minilm-l6"`` (default, 384-d, offline, text only) and
``"qwen3vl"`` / ``"qwen3-vl-embedding-2b"`` (2048-d or a Matryoshka prefix, text + images,
needs a local model folder). A Qwen3-VL store name carries its dim, e.g.
``"qwen3-vl-embedding-2b@512"``; that form is accepted here too.
"""

from __future__ import annotations

import os

from tactus_memory.spaces.base import Space

MINILM_ALIASES = ("minilm", "minilm-l6")
QWEN3VL_ALIASES = ("qwen3vl", "qwen3-vl-embedding-2b")
KNOWN_SPACES = MINILM_ALIASES + QWEN3VL_ALIASES


def get_space(
    name: str = "minilm",
    path: str | os.PathLike[str] | None = None,
    dim: int | None = None,
) -> Space:
    """Build a space by registry name (cheap: models load on first use).

    ``path`` is a local model folder (required for Qwen3-VL, optional for MiniLM);
    ``dim`` is the Matryoshka output size for Qwen3-VL (MiniLM only accepts 384).
    """
    if not isinstance(name, str):
        raise ValueError(f"space name must be a string, got {type(name).__name__}")
    key = name.strip().lower()
    if "@" in key:
        base, _, suffix = key.partition("@")
        if base in QWEN3VL_ALIASES and suffix.isdigit():
            if dim is not None and dim != int(suffix):
                raise ValueError(f"space {name!r} names dim {suffix}, but dim={dim} was given")
            key, dim = base, int(suffix)
    if key in MINILM_ALIASES:
        from tactus_memory.spaces.minilm import MINILM_DIM, MiniLMSpace

        if dim is not None and dim != MINILM_DIM:
            raise ValueError(f"space 'minilm-l6' has dim {MINILM_DIM}; dim={dim} is not possible")
        return MiniLMSpace(path)
    if key in QWEN3VL_ALIASES:
        from tactus_memory.spaces.qwen3vl import Qwen3VLSpace

        if path is None:
            raise ValueError(
                "space 'qwen3-vl-embedding-2b' needs path= a local Qwen3-VL-Embedding-2B folder"
            )
        return Qwen3VLSpace(path, dim=dim)  # None: the model's full size (2048 for the 2B)
    raise ValueError(f"unknown space {name!r}; known spaces: {', '.join(KNOWN_SPACES)}")


__all__ = ["KNOWN_SPACES", "Space", "get_space"]
