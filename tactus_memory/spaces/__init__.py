"""Embedding spaces. ``get_space(name, path=None, dim=None)`` builds one by its registered
name (:mod:`tactus_memory.senses.plugins`: ``@register("minilm", "minilm-l6")`` on the class).

Built in: ``"minilm"`` / ``"minilm-l6"`` (default, 384-d, offline, text only) and
``"qwen3vl"`` / ``"qwen3-vl-embedding-2b"`` (2048-d or a Matryoshka prefix, text + images,
needs a local model folder). A store name may carry its dim, e.g.
``"qwen3-vl-embedding-2b@512"``; that form is accepted here too.
"""

from __future__ import annotations

import os

from tactus_memory.senses.plugins import lookup
from tactus_memory.spaces.base import Space


def get_space(
    name: str = "minilm",
    path: str | os.PathLike[str] | None = None,
    dim: int | None = None,
) -> Space:
    """Build a space by registered name (cheap: models load on first use).

    ``path`` is a local model folder (required by spaces that ``needs_path``, e.g. Qwen3-VL);
    ``dim`` the output size (a Matryoshka prefix for Qwen3-VL; MiniLM only gives 384).
    """
    if not isinstance(name, str):
        raise ValueError(f"space name must be a string, got {type(name).__name__}")
    key = name.strip().lower()
    base, at, suffix = key.partition("@")
    if at and suffix.isdigit():
        if dim is not None and dim != int(suffix):
            raise ValueError(f"space {name!r} names dim {suffix}, but dim={dim} was given")
        key, dim = base, int(suffix)
    cls = lookup("space", key)
    return cls.create(None if path is None else str(path), dim)
