"""``tactus pretrain`` and ``tactus train``: the touch encoder's recipe from STAG files."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import typer

from tactus_memory.cli.app import app

HOLDOUT_HELP = (
    "recordings kept out of training (and pretraining) and scored: none | "
    "one-per-object@SUBSTR (per object, the lowest-id recording with valid frames in the "
    "--data file whose path contains SUBSTR) | recordings@NAME,NAME"
)


def _threads(n: int) -> None:
    import torch

    if n > 0:
        torch.set_num_threads(n)


@app.command("pretrain")
def pretrain_cmd(
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    out: Path = typer.Option(..., "--out", help="MAE checkpoint to write (.safetensors)"),
    model: str = typer.Option("tactus-lite", "--model", help="trunk architecture"),
    steps: int = typer.Option(400, "--steps", help="optimizer steps (shipped recipe: 400)"),
    batch: int = typer.Option(128, "--batch", help="frames per step"),
    lr: float = typer.Option(1.5e-3, "--lr"),
    seed: int = typer.Option(0, "--seed"),
    holdout: str = typer.Option("none", "--holdout", help=HOLDOUT_HELP),
    device: str = typer.Option("auto", "--device"),
    threads: int = typer.Option(2, "--threads", help="torch CPU threads (0: torch default)"),
    resume: bool = typer.Option(False, "--resume", help="continue from OUT.resume.pt"),
) -> None:
    """MAE-pretrain a trunk on ALL frames of the files (valid or not), minus --holdout."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    _threads(threads)
    from tactus_memory.touch.data import STAG_GLOVE
    from tactus_memory.touch.pretrain import PretrainConfig, pretrain
    from tactus_memory.touch.train import _resolve_device, holdout_recordings, load_data

    d = load_data(data)
    d.check_dynamic_range(STAG_GLOVE)  # per source file; raises DynamicRangeError
    excl = holdout_recordings(d, holdout)
    cfg = PretrainConfig(
        model=model,
        steps=steps,
        batch=batch,
        lr=lr,
        seed=seed,
        warmup=max(1, min(150, steps // 20)),
    )
    summary = pretrain(
        d.calibrated(STAG_GLOVE),
        d.recording_id,
        excl,
        out,
        cfg,
        fingerprint=d.fingerprint(),
        device=_resolve_device(device),
        resume=resume,
    )
    summary.pop("history", None)
    summary["excluded_recording_names"] = [d.recordings[r] for r in excl]
    typer.echo(json.dumps(summary, indent=2))


@app.command("train")
def train_cmd(
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    out: Path = typer.Option(..., "--out", help="checkpoint to write (.safetensors)"),
    model: str = typer.Option("tactus-lite", "--model", help="architecture in configs/"),
    space: str = typer.Option("minilm", "--space", help="frozen text space (get_space name)"),
    pretrained: Path | None = typer.Option(None, "--pretrained", help="MAE checkpoint"),
    steps: int = typer.Option(600, "--steps", help="optimizer steps (shipped recipe: 600)"),
    batch: int = typer.Option(64, "--batch", help="windows per step"),
    lr: float = typer.Option(1e-3, "--lr"),
    seed: int = typer.Option(0, "--seed"),
    device: str = typer.Option("auto", "--device", help="auto | cpu | cuda"),
    holdout: str = typer.Option("none", "--holdout", help=HOLDOUT_HELP),
    half: bool = typer.Option(False, "--half", help="store float16 weights"),
    threads: int = typer.Option(2, "--threads", help="torch CPU threads (0: torch default)"),
    resume: bool = typer.Option(False, "--resume", help="continue from OUT.resume.pt"),
    positives: str = typer.Option(
        "valid", "--positives", help="valid (labelled frames) | contact (+ every contact frame)"
    ),
) -> None:
    """Train the touch encoder against centred class-phrase targets; report held-out accuracy."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    _threads(threads)
    from tactus_memory.spaces import get_space
    from tactus_memory.touch.targets import build_targets, target_report
    from tactus_memory.touch.train import (
        TrainConfig,
        fit,
        holdout_recordings,
        load_data,
        prepare_data,
    )

    d = load_data(data)
    td = prepare_data(d, holdout_recordings(d, holdout), positives=positives)
    sp = get_space(space)
    targets = build_targets(sp, td.classes)
    typer.echo(json.dumps({"target_geometry": target_report(targets)}, indent=2))
    cfg = TrainConfig(
        model=model,
        steps=steps,
        batch=batch,
        lr=lr,
        seed=seed,
        half=half,
        warmup=max(1, min(150, steps // 20)),
    )
    summary = fit(
        td,
        targets,
        cfg,
        out,
        space_dim=sp.dim,
        pretrained=pretrained,
        device=device,
        resume=resume,
    )
    summary.pop("heldout_per_recording", None)
    typer.echo(json.dumps(summary, indent=2))
