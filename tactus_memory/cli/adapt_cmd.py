"""``tactus adapt``: fine-tune the shipped touch encoder (or any checkpoint) on your own few
labelled grasps, on a CPU (``tactus_memory.training.adapt``): from a ``.npz`` or a bag of your
sensor, or from what you taught a memory (``--data ./memory``)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Annotated

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import CheckpointOut, Resume, Seed, Threads, set_threads
from tactus_memory.cli.sensor_opts import SensorData
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail, resolve_or_exit
from tactus_memory.signatures import grouped

Base = Annotated[
    Path | None,
    typer.Option("--base", help="checkpoint to start from (default: the shipped encoder)"),
]


@app.command("adapt")
@grouped(source=SensorData)
def adapt_cmd(
    out: CheckpointOut,
    base: Base = None,
    steps: Annotated[int, typer.Option("--steps", help="steps on the cached features")] = 300,
    lr: Annotated[float, typer.Option("--lr")] = 1e-3,
    copies: Annotated[
        int, typer.Option("--copies", help="feature rows per window (1 + augmented copies)")
    ] = 8,
    anchor: Annotated[
        float, typer.Option("--anchor", help="pull towards the base projector (L2-SP)")
    ] = 0.05,
    tune: Annotated[
        str, typer.Option("--tune", help="what trains: projector | fusion (+ the frame fusion)")
    ] = "projector",
    sense: Annotated[
        str, typer.Option("--sense", help="with a memory: the taught sense")
    ] = "touch",
    seed: Seed = 0,
    threads: Threads = 2,
    resume: Resume = False,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
    *,
    source: SensorData,
) -> None:
    """Fine-tune a touch checkpoint on a few labelled grasps: --data FILE.npz (or --bag with
    --labels), or --data MEMORY_FOLDER to train on the grasps taught there (tactus teach).
    The trunk is frozen and its output cached once; the projector trains (--tune fusion:
    the frame fusion too). The sensor profile is the base checkpoint's. Then
    `tactus reembed --checkpoint OUT` puts a memory's touch on the adapted encoder."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from tactus_memory.errors import InvalidInputError
    from tactus_memory.touch.checkpoint import default_checkpoint_path, load_checkpoint
    from tactus_memory.touch.profile import SensorProfile
    from tactus_memory.training.adapt import AdaptConfig, adapt
    from tactus_memory.training.adapt_data import (
        grasps_from_data,
        grasps_from_memory,
        is_memory_folder,
    )

    try:
        cfg = AdaptConfig(steps=steps, lr=lr, copies=copies, anchor=anchor, seed=seed, tune=tune)
    except InvalidInputError as exc:
        raise typer.BadParameter(str(exc)) from exc
    path = base or default_checkpoint_path()
    if not path.is_file():
        fail(f"--base: no such checkpoint: {path}")
    set_threads(threads)
    ck = load_checkpoint(path)
    assert ck.model is not None
    k, shape = int(ck.model.cfg.frames), tuple(ck.model.cfg.frame_shape)
    memories = [p for p in source.data or () if is_memory_folder(p)]
    if memories:
        if len(memories) > 1 or len(source.data) > 1 or source.bag:
            fail("--data MEMORY: give one memory folder and no other --data or --bag")
        grasps, sp = grasps_from_memory(memories[0], k, shape, sense=sense)  # type: ignore[arg-type]
    else:
        missing = [str(p) for p in source.data or () if not p.exists()]
        if missing:
            fail(f"--data: no such file or folder: {', '.join(missing)}")
        data, profile = source.load(SensorProfile.from_dict(ck.meta["calibration"]))
        if tuple(profile.shape) != shape:
            fail(f"the sensor reads {profile.shape} frames; {path.name} reads {shape}")
        names = [str(p) for p in (source.data or source.bag)]
        grasps = grasps_from_data(data, profile, k, ", ".join(names))
        sp = resolve_or_exit(space, space_path, space_dim)
    summary = adapt(ck, grasps, sp, out, cfg, resume=resume)
    typer.echo(json.dumps(summary, indent=2))
