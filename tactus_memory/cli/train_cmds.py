"""``tactus pretrain``, ``tactus train`` and ``tactus distill``: the touch encoder's recipe
from STAG files, or from your own sensor's recordings (.npz or a bag, ``sensor_opts.py``)."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    Augment,
    Balance,
    Batch,
    CheckpointOut,
    Consecutive,
    Device,
    Dropout,
    Half,
    InputBlur,
    InputGamma,
    LearningRate,
    ModelName,
    Positives,
    PreciseBn,
    Pretrained,
    Resume,
    Seed,
    Steps,
    Threads,
    TrainHoldout,
    WeightDecay,
    output_folder,
    set_threads,
)
from tactus_memory.cli.sensor_opts import SensorData
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, resolve_or_exit
from tactus_memory.signatures import grouped

#: MAE pretraining's frames per step: the shipped recipe's on a GPU; on a CPU a quarter of it
#: (a step of 128 took 13-25 s on a loaded 2-core machine, issue 47)
PRETRAIN_BATCH_GPU = 128
PRETRAIN_BATCH_CPU = 32


@app.command("pretrain")
@grouped(source=SensorData)
def pretrain_cmd(
    *,
    source: SensorData,
    out: Path = typer.Option(..., "--out", help="MAE checkpoint to write (.safetensors)"),
    model: str = typer.Option("tactus-lite", "--model", help="trunk architecture"),
    steps: int = typer.Option(400, "--steps", help="optimizer steps (shipped recipe: 400)"),
    batch: int | None = typer.Option(
        None,
        "--batch",
        help=f"frames per step (default {PRETRAIN_BATCH_GPU} on a GPU, the shipped recipe; "
        f"{PRETRAIN_BATCH_CPU} on a CPU)",
    ),
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
    output_folder(out)
    from tactus_memory.training.pretrain import PretrainConfig, pretrain, recipe_warmup
    from tactus_memory.training.train import _resolve_device, holdout_recordings

    d, profile = source.load()
    d.check_dynamic_range(profile)  # per source file; raises DynamicRangeError
    excl = holdout_recordings(d, holdout)
    warmup = recipe_warmup(steps)
    device = _resolve_device(device)
    if batch is None:
        batch = PRETRAIN_BATCH_GPU if device.startswith("cuda") else PRETRAIN_BATCH_CPU
    cfg = PretrainConfig(model=model, steps=steps, batch=batch, lr=lr, seed=seed, warmup=warmup)
    summary = pretrain(
        d.calibrated(profile),
        d.recording_id,
        excl,
        out,
        cfg,
        fingerprint=d.fingerprint(),
        device=device,
        resume=resume,
    )
    summary.pop("history", None)
    summary["excluded_recording_names"] = [d.recordings[r] for r in excl]
    typer.echo(json.dumps(summary, indent=2))


@dataclass(frozen=True)
class Recipe:
    """The options ``tactus train`` and ``tactus distill`` share (one group: the ladder's
    options, checkpoints README)."""

    out: CheckpointOut
    model: ModelName = "tactus-lite"
    pretrained: Pretrained = None
    steps: Steps = 600
    batch: Batch = 64
    lr: LearningRate = 1e-3
    seed: Seed = 0
    device: Device = "auto"
    holdout: TrainHoldout = "none"
    half: Half = False
    threads: Threads = 2
    resume: Resume = False
    space: SpaceName = None
    space_path: SpacePath = None
    space_dim: SpaceDim = None
    positives: Positives = "valid"
    balance: Balance = "none"
    consecutive: Consecutive = 0.0
    augment: Augment = "default"
    weight_decay: WeightDecay = 0.05
    precise_bn: PreciseBn = 0
    input_gamma: InputGamma = None
    input_blur: InputBlur = None
    dropout: Dropout = None


def training_run(r: Recipe, source: SensorData) -> tuple[Any, Any, Any, int]:
    """The data, targets and TrainConfig of ``tactus train`` / ``tactus distill`` from their
    shared options. Returns (TrainData, Targets, TrainConfig, the space's dim)."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from tactus_memory.training.augment import AUGMENT_PRESETS, augment_preset
    from tactus_memory.training.train import BALANCE, POSITIVES

    # refuse a typo before the data is read and the targets embedded
    for flag, value, choices in (
        ("--positives", r.positives, POSITIVES),
        ("--balance", r.balance, BALANCE),
        ("--augment", r.augment, tuple(AUGMENT_PRESETS)),
    ):
        if value not in choices:
            raise typer.BadParameter(f"{flag} must be one of {', '.join(choices)}, got {value!r}")
    set_threads(r.threads)
    output_folder(r.out)
    sp = resolve_or_exit(r.space, r.space_path, r.space_dim)
    from tactus_memory.touch.targets import build_targets, target_report
    from tactus_memory.training.pretrain import recipe_warmup
    from tactus_memory.training.train import (
        TrainConfig,
        holdout_recordings,
        prepare_data,
    )

    d, profile = source.load()
    td = prepare_data(d, holdout_recordings(d, r.holdout), positives=r.positives, profile=profile)
    targets = build_targets(sp, td.classes)
    typer.echo(json.dumps({"target_geometry": target_report(targets)}, indent=2))
    fields = ("model", "steps", "batch", "lr", "seed", "half", "consecutive", "weight_decay")
    fields += ("precise_bn",)
    cfg = TrainConfig(balance=r.balance, **{f: getattr(r, f) for f in fields})
    cfg.warmup = recipe_warmup(cfg.steps)
    cfg.augment = augment_preset(r.augment)
    model_opts = {"input_gamma": r.input_gamma, "input_blur": r.input_blur, "dropout": r.dropout}
    cfg.model_overrides = {k: v for k, v in model_opts.items() if v is not None}
    return td, targets, cfg, sp.dim


@app.command("train")
@grouped(source=SensorData, recipe=Recipe)
def train_cmd(*, source: SensorData, recipe: Recipe) -> None:
    """Train the touch encoder against centred class-phrase targets embedded in the frozen
    space (--space, default MiniLM); report held-out accuracy. The checkpoint records the
    space's name, dim and model fingerprint, so it only registers in a memory of that space."""
    td, targets, cfg, dim = training_run(recipe, source)
    from tactus_memory.training.train import fit

    r = recipe
    summary = fit(
        td, targets, cfg, r.out, space_dim=dim, pretrained=r.pretrained, device=r.device,
        resume=r.resume,
    )  # fmt: skip
    summary.pop("heldout_per_recording", None)
    typer.echo(json.dumps(summary, indent=2))


@app.command("distill")
@grouped(source=SensorData, recipe=Recipe)
def distill_cmd(
    teacher: list[Path] = typer.Option(
        ..., "--teacher", help="teacher checkpoint (same space); repeat to average several"
    ),
    cosine_weight: float = typer.Option(
        1.0, "--cosine-weight", help="weight of mean(1 - cos(student, teachers' mean))"
    ),
    relational_weight: float = typer.Option(
        0.0, "--relational-weight", help="weight of the batch similarity-matrix MSE"
    ),
    *,
    source: SensorData,
    recipe: Recipe,
) -> None:
    """Train a (fast) student as `tactus train` does, plus a loss pulling its embeddings
    towards the teachers' (mean of their unit embeddings of the same augmented windows).
    Teachers must be in the student's space and calibration; their sha256 are recorded."""
    from tactus_memory.training.distill import DistillConfig, TeacherMismatchError, distill

    try:
        dcfg = DistillConfig(cosine_weight=cosine_weight, relational_weight=relational_weight)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from exc
    missing = [str(p) for p in teacher if not p.is_file()]
    if missing:
        raise typer.BadParameter(f"--teacher: no such file: {', '.join(missing)}")
    td, targets, cfg, dim = training_run(recipe, source)
    r = recipe
    try:
        summary = distill(
            td, targets, cfg, r.out, teacher, space_dim=dim, dcfg=dcfg, pretrained=r.pretrained,
            device=r.device, resume=r.resume,
        )  # fmt: skip
    except TeacherMismatchError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    summary.pop("heldout_per_recording", None)
    typer.echo(json.dumps(summary, indent=2))
