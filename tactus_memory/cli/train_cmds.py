"""``tactus pretrain`` and ``tactus train``: the touch encoder's recipe from STAG files."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    CheckpointOut,
    LearningRate,
    Resume,
    Seed,
    StagFiles,
    Threads,
    TrainHoldout,
    set_threads,
)
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, resolve_or_exit


@app.command("pretrain")
def pretrain_cmd(
    data: StagFiles,
    out: Path = typer.Option(..., "--out", help="MAE checkpoint to write (.safetensors)"),
    model: str = typer.Option("tactus-lite", "--model", help="trunk architecture"),
    steps: int = typer.Option(400, "--steps", help="optimizer steps (shipped recipe: 400)"),
    batch: int = typer.Option(128, "--batch", help="frames per step"),
    lr: LearningRate = 1.5e-3,
    seed: Seed = 0,
    holdout: TrainHoldout = "none",
    device: str = typer.Option("auto", "--device"),
    threads: Threads = 2,
    resume: Resume = False,
) -> None:
    """MAE-pretrain a trunk on ALL frames of the files (valid or not), minus --holdout."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    set_threads(threads)
    from tactus_memory.touch.pretrain import PretrainConfig, pretrain, recipe_warmup
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.train import _resolve_device, holdout_recordings, load_data

    d = load_data(data)
    d.check_dynamic_range(STAG_GLOVE)  # per source file; raises DynamicRangeError
    excl = holdout_recordings(d, holdout)
    warmup = recipe_warmup(steps)
    cfg = PretrainConfig(model=model, steps=steps, batch=batch, lr=lr, seed=seed, warmup=warmup)
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
    data: StagFiles,
    out: CheckpointOut,
    model: str = typer.Option("tactus-lite", "--model", help="architecture in configs/"),
    pretrained: Path | None = typer.Option(None, "--pretrained", help="MAE checkpoint"),
    steps: int = typer.Option(600, "--steps", help="optimizer steps (shipped recipe: 600)"),
    batch: int = typer.Option(64, "--batch", help="windows per step"),
    lr: LearningRate = 1e-3,
    seed: Seed = 0,
    device: str = typer.Option("auto", "--device", help="auto | cpu | cuda"),
    holdout: TrainHoldout = "none",
    half: bool = typer.Option(False, "--half", help="store float16 weights"),
    threads: Threads = 2,
    resume: Resume = False,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
    positives: str = typer.Option(
        "valid", "--positives", help="valid (labelled frames) | contact (+ every contact frame)"
    ),
    balance: str = typer.Option(
        "none", "--balance", help="none | recording | class: how batches draw training windows"
    ),
    consecutive: float = typer.Option(
        0.0, "--consecutive", help="share of training windows cut as K consecutive frames"
    ),
    augment: str = typer.Option("default", "--augment", help="default | strong | pressed-noise"),
    weight_decay: float = typer.Option(0.05, "--weight-decay", help="AdamW weight decay"),
    input_gamma: float | None = typer.Option(
        None, "--input-gamma", help="model input: pressure ** gamma (default: the config's)"
    ),
    input_blur: float | None = typer.Option(
        None, "--input-blur", help="model input: Gaussian blur sigma, px (default: the config's)"
    ),
    dropout: float | None = typer.Option(
        None, "--dropout", help="Dropout2d on trunk features (default: the config's)"
    ),
) -> None:
    """Train the touch encoder against centred class-phrase targets embedded in the frozen
    space (--space, default MiniLM); report held-out accuracy. The checkpoint records the
    space's name, dim and model fingerprint, so it only registers in a memory of that space."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from tactus_memory.touch.augment import AUGMENT_PRESETS, augment_preset
    from tactus_memory.touch.train import BALANCE, POSITIVES

    # refuse a typo before the data is read and the targets embedded
    for flag, value, choices in (
        ("--positives", positives, POSITIVES),
        ("--balance", balance, BALANCE),
        ("--augment", augment, tuple(AUGMENT_PRESETS)),
    ):
        if value not in choices:
            raise typer.BadParameter(f"{flag} must be one of {', '.join(choices)}, got {value!r}")
    set_threads(threads)
    sp = resolve_or_exit(space, space_path, space_dim)
    from tactus_memory.touch.pretrain import recipe_warmup
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
    targets = build_targets(sp, td.classes)
    typer.echo(json.dumps({"target_geometry": target_report(targets)}, indent=2))
    warmup = recipe_warmup(steps)
    cfg = TrainConfig(
        model=model, steps=steps, batch=batch, lr=lr, seed=seed, half=half, warmup=warmup
    )
    # the ladder's options (checkpoints README): batches, windows, regularisation, input shaping
    cfg.balance, cfg.consecutive, cfg.weight_decay = balance, consecutive, weight_decay
    cfg.augment = augment_preset(augment)
    model_opts = {"input_gamma": input_gamma, "input_blur": input_blur, "dropout": dropout}
    cfg.model_overrides = {k: v for k, v in model_opts.items() if v is not None}
    summary = fit(
        td, targets, cfg, out, space_dim=sp.dim, pretrained=pretrained, device=device, resume=resume
    )
    summary.pop("heldout_per_recording", None)
    typer.echo(json.dumps(summary, indent=2))
