"""The one mixed-precision rule of training: bf16 autocast of forward passes on CUDA, float32
on CPU (pretraining, training, the teachers' forwards in distillation, the GPU step probe)."""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext

import torch


def autocast(device: str | torch.device, enabled: bool = True) -> AbstractContextManager:
    """bf16 autocast when ``device`` is CUDA and ``enabled``; a no-op context otherwise."""
    if enabled and str(device).startswith("cuda"):
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return nullcontext()
