"""Tiny random Qwen3-VL model folders for the end-to-end space tests.

``build_tiny_qwen3vl`` (tests/test_qwen3vl.py) saves a real local folder: config.json, the
safetensors weights, a byte-level BPE tokenizer with the Qwen special tokens and the image
processor config. :func:`perturbed_copy` makes "another model" of the same architecture (its
weights shifted), as a fine-tune or another download would be.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np


def perturbed_copy(src: Path, dst: Path, *, scale: float = 0.05, seed: int = 1) -> Path:
    """Copy a model folder and add noise to every floating weight of its safetensors files."""
    import torch
    from safetensors import safe_open
    from safetensors.torch import save_file

    shutil.copytree(src, dst)
    gen = torch.Generator().manual_seed(seed)
    for weights in sorted(dst.glob("*.safetensors")):
        with safe_open(str(weights), framework="pt") as f:
            meta = f.metadata()
            tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open API)
        for k, v in tensors.items():
            if v.is_floating_point():
                tensors[k] = v + scale * torch.randn(v.shape, generator=gen, dtype=v.dtype)
        save_file(tensors, str(weights), metadata=meta)
    return dst


def png_bytes(seed: int, size: tuple[int, int] = (64, 96), fmt: str = "PNG") -> bytes:
    """A random RGB picture (H, W) = ``size`` encoded as ``fmt``."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    arr = rng.integers(0, 256, (*size, 3), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format=fmt)
    return buf.getvalue()
