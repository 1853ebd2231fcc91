"""Helpers shared by the command modules."""

from __future__ import annotations


def set_threads(n: int) -> None:
    """Cap torch's CPU threads at ``n`` (0: torch's default)."""
    import torch

    if n > 0:
        torch.set_num_threads(n)
