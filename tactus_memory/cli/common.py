"""Helpers shared by the command modules."""

from __future__ import annotations

import typer

#: ``--data``, shared by every command that reads STAG files
DATA_OPTION = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat")


def set_threads(n: int) -> None:
    """Cap torch's CPU threads at ``n`` (0: torch's default)."""
    import torch

    if n > 0:
        torch.set_num_threads(n)
