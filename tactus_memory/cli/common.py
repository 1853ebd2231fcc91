"""Helpers shared by the command modules, and the options several commands declare alike.

Options are ``Annotated`` aliases (as in :mod:`tactus_memory.cli.space_opts`): a command
declares ``seed: Seed = 0`` and keeps its own default; the flag and its help live here once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath
from tactus_memory.identity import DEFAULT_TENANT
from tactus_memory.limits import MAX_WINDOW_FRAMES

#: ``--data``, shared by every command that reads STAG files (required)
StagFiles = Annotated[
    list[Path], typer.Option("--data", help="STAG metadata.mat or folder; repeat")
]

#: ``--windows``: touch answers as single windows, not grasps (the default, group=auto)
Windows = Annotated[
    bool,
    typer.Option(
        "--windows",
        help="Touch as single windows; by default a touch answer is a grasp (the contiguous "
        "windows of one hold, scored together).",
    ),
]

#: ``--touch NAME=CKPT`` (serve, ingest): a touch sense for the user's own sensor
TouchSenses = Annotated[
    list[str] | None,
    typer.Option(
        "--touch",
        metavar="NAME=CKPT",
        help="A touch sense for your own sensor: NAME its sense name (writes name it with "
        "?sense=NAME; ingest maps a topic to it), CKPT its `tactus train` checkpoint (the frame "
        "shape comes from its sensor profile); repeatable. A sense the store already records "
        "needs no flag (serve: env TACTUS_TOUCH_SENSES as JSON {name: checkpoint}).",
    ),
]

# ----------------------------------------------------------------------------- a memory store
#: ``--data`` of the commands that open a memory store (search, sessions, ingest, export)
MemoryData = Annotated[
    str | None,
    typer.Option(
        "--data",
        help="Memory location: a directory or s3:// gs:// az:// URI (default $TACTUS_DATA or "
        "./memory).",
    ),
]
#: ``--ray`` / ``--ray-address`` of the bulk commands (ingest, reembed): Ray Data jobs
#: (:mod:`tactus_memory.recordings.ray_jobs`); ``--ray`` alone joins $RAY_ADDRESS, else starts Ray
#: here
UseRay = Annotated[
    bool,
    typer.Option(
        "--ray",
        help="Run as Ray Data jobs (needs the ray extra): on the cluster at --ray-address or "
        "$RAY_ADDRESS, else on a Ray instance started here.",
    ),
]
RayAddress = Annotated[
    str | None,
    typer.Option(
        "--ray-address",
        metavar="ADDRESS",
        help="The Ray cluster (e.g. auto, ray://head:10001, local); implies --ray.",
    ),
]
#: ``--ray-workers``: one-CPU Ray workers of a ``--ray`` job
RayWorkers = Annotated[
    int | None,
    typer.Option(
        "--ray-workers", min=1, help="With --ray: workers (one CPU each); default every CPU."
    ),
]


@dataclass(frozen=True)
class RayJob:
    """``--ray``, ``--ray-address``, ``--ray-workers`` of the bulk commands (ingest, reembed):
    one group of options (:func:`tactus_memory.signatures.grouped`)."""

    ray: UseRay = False
    ray_address: RayAddress = None
    ray_workers: RayWorkers = None

    def cluster(self) -> str | None:
        """The Ray cluster the options name (None: no Ray, the job runs here)."""
        if not self.ray and self.ray_address is None:
            return None
        from tactus_memory.recordings.ray_jobs import default_address

        return default_address(self.ray_address)


#: ``--url`` of the commands that ask a memory: a running ``tactus serve`` answers instead
#: (no model loaded in the shell; see :mod:`tactus_memory.cli.remote`)
ServerUrl = Annotated[
    str | None,
    typer.Option(
        "--url",
        envvar="TACTUS_URL",
        help="Ask the server at this URL (e.g. http://127.0.0.1:8000, as `make run` serves) "
        "instead of opening --data: no model loads here, so it answers at once (env "
        "TACTUS_URL).",
    ),
]
#: ``--tenant`` of the commands that open a memory store: whose memory (README "Keys and
#: tenants"); with ``--url`` it is sent as the operator's tenant header (a key's own wins)
Tenant = Annotated[
    str,
    typer.Option(
        "--tenant",
        envvar="TACTUS_TENANT",
        help="The tenant whose memory to open (env TACTUS_TENANT; default: default).",
        show_envvar=False,
    ),
]
#: the bearer token sent with ``--url`` (the server's ``--token``)
ServerToken = Annotated[
    str | None,
    typer.Option(
        "--token",
        envvar="TACTUS_TOKEN",
        help="With --url: the server's token (env TACTUS_TOKEN).",
        show_envvar=False,
    ),
]
#: the scope options every question shares (search, last, first, count, timeline)
Senses = Annotated[
    list[str] | None,
    typer.Option("--sense", help="Only these senses (repeatable); default all with rows."),
]
Session = Annotated[str | None, typer.Option("--session", help="Only this session.")]
After = Annotated[
    float | None, typer.Option("--after", help="Items overlapping t >= AFTER (seconds).")
]
Before = Annotated[
    float | None, typer.Option("--before", help="Items overlapping t <= BEFORE (seconds).")
]
AsJson = Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")]
# how touch streams are cut into windows (`tactus serve`, `tactus ingest`); unset: the touch
# sense's own window (its checkpoint's K, 8 for the shipped one) and stride
TouchWindow = Annotated[
    int | None,
    typer.Option("--window", min=1, max=MAX_WINDOW_FRAMES, help="Touch frames per window."),
]
TouchStride = Annotated[
    int | None,
    typer.Option("--stride", min=1, max=MAX_WINDOW_FRAMES, help="Frames between window starts."),
]


@dataclass(frozen=True)
class Window:
    """``--sense``, ``--after``, ``--before``: a time window over some senses, one group of
    options (:func:`tactus_memory.signatures.grouped`; ``tactus timeline``)."""

    sense: Senses = None
    after: After = None
    before: Before = None

    def filters(self) -> dict[str, Any]:
        """The library's scope keywords (``memory.search(q, **filters)``)."""
        return {"senses": self.sense or None, "after": self.after, "before": self.before}


ForceMin = Annotated[
    float | None, typer.Option("--force-min", help="Touch only: force at least this.")
]
ForceMax = Annotated[
    float | None, typer.Option("--force-max", help="Touch only: force at most this.")
]
AreaMin = Annotated[
    float | None, typer.Option("--area-min", help="Touch only: contact area (share) >= this.")
]
Regions = Annotated[
    str | None,
    typer.Option("--regions", help="Touch only: these regions active (e.g. thumb,index)."),
]
Grip = Annotated[
    str | None,
    typer.Option("--grip", help="Touch only: pinch, tripod, power, press, other or none."),
]


Sort = Annotated[
    str | None,
    typer.Option(
        "--sort",
        help="Order by a touch facet or time: force, -force, area, -area, t, -t (first and "
        "last: the ends of that order, e.g. first --sort -force: the firmest).",
    ),
]


@dataclass(frozen=True)
class Scope(Window):
    """A question's scope: the window, ``--session`` and the touch facet filters (search,
    last, first, count)."""

    session: Session = None
    force_min: ForceMin = None
    force_max: ForceMax = None
    area_min: AreaMin = None
    regions: Regions = None
    grip: Grip = None

    def filters(self) -> dict[str, Any]:
        facets = ("force_min", "force_max", "area_min", "regions", "grip")
        return {
            **super().filters(),
            "session": self.session,
            **{f: getattr(self, f) for f in facets},
        }


@dataclass(frozen=True)
class Source:
    """The memory a command reads: a store here (``--data``, in the space the space options
    name) or a running server (``--url``, ``--token``), and whose (``--tenant``); one group of
    options."""

    data: MemoryData = None
    url: ServerUrl = None
    token: ServerToken = None
    space: SpaceName = None
    space_path: SpacePath = None
    space_dim: SpaceDim = None
    tenant: Tenant = DEFAULT_TENANT

    @property
    def spaces(self) -> tuple[str | None, str | None, int | None]:
        """The space options, in :func:`tactus_memory.cli.memory_cmds._open`'s order."""
        return self.space, self.space_path, self.space_dim


#: ``--data`` of the long-running processes (serve, maintain), whose settings read TACTUS_DATA
ServiceData = Annotated[
    str | None,
    typer.Option("--data", help="Memory directory or URI (s3://, gs://, az://) (env TACTUS_DATA)."),
]

# ----------------------------------------------------------------------------- training
#: torch's CPU threads for the command (each command sets its own default)
Threads = Annotated[int, typer.Option("--threads", help="torch CPU threads (0: torch default)")]
Seed = Annotated[int, typer.Option("--seed")]
LearningRate = Annotated[float, typer.Option("--lr")]
#: the checkpoint a training command writes (tactus train, tactus baseline train; required)
CheckpointOut = Annotated[Path, typer.Option("--out", help="checkpoint to write (.safetensors)")]
Resume = Annotated[bool, typer.Option("--resume", help="continue from OUT.resume.pt")]
#: the recordings ``tactus pretrain`` and ``tactus train`` keep out (the grammar of
#: :func:`tactus_memory.training.train.holdout_recordings`)
TrainHoldout = Annotated[
    str,
    typer.Option(
        "--holdout",
        help="recordings kept out of training (and pretraining) and scored: none | "
        "one-per-object@SUBSTR (per object, the lowest-id recording with valid frames in the "
        "--data file whose path contains SUBSTR) | recordings@NAME,NAME",
    ),
]
#: the recipe options ``tactus train`` and ``tactus distill`` share (the ladder's options:
#: checkpoints README); each command keeps its own defaults
ModelName = Annotated[str, typer.Option("--model", help="architecture in configs/")]
Pretrained = Annotated[Path | None, typer.Option("--pretrained", help="MAE checkpoint")]
Steps = Annotated[int, typer.Option("--steps", help="optimizer steps")]
Batch = Annotated[int, typer.Option("--batch", help="windows per step")]
Device = Annotated[str, typer.Option("--device", help="auto | cpu | cuda")]
Half = Annotated[bool, typer.Option("--half", help="store float16 weights")]
Positives = Annotated[
    str,
    typer.Option("--positives", help="valid (labelled frames) | contact (+ every contact frame)"),
]
Balance = Annotated[
    str,
    typer.Option("--balance", help="none | recording | class: how batches draw training windows"),
]
Consecutive = Annotated[
    float,
    typer.Option("--consecutive", help="share of training windows cut as K consecutive frames"),
]
Augment = Annotated[str, typer.Option("--augment", help="default | strong | pressed-noise")]
WeightDecay = Annotated[float, typer.Option("--weight-decay", help="AdamW weight decay")]
PreciseBn = Annotated[
    int,
    typer.Option(
        "--precise-bn",
        help="after training, recompute BatchNorm statistics over N batches of training windows "
        "(0: off, the STAG recipe); for short runs and small frames (touch/training/precise_bn.py)",
    ),
]


def _override(flag: str, what: str) -> Any:
    """An option that overrides one field of the model's config (default: the config's)."""
    return typer.Option(flag, help=f"{what} (default: the config's)")


InputGamma = Annotated[float | None, _override("--input-gamma", "model input: pressure ** gamma")]
InputBlur = Annotated[
    float | None, _override("--input-blur", "model input: Gaussian blur sigma, px")
]
Dropout = Annotated[float | None, _override("--dropout", "Dropout2d on trunk features")]
#: the recordings ``tactus eval`` and ``tactus baseline eval`` score
ScoredHoldout = Annotated[
    str | None,
    typer.Option(
        "--holdout",
        help="score exactly the recordings a `tactus train --holdout SPEC` run held out (same "
        "grammar: none | one-per-object@SUBSTR | recordings@NAME,NAME); replaces --split. Pass "
        "the same --data files in the same order as the training run",
    ),
]
Split = Annotated[
    str,
    typer.Option(
        "--split",
        help="test: each file's 'test' frames (a file without splits, e.g. weights, is scored "
        "whole); all: every valid frame",
    ),
]


def output_folder(path: Path) -> Path:
    """``path`` with its folder made (``--out runs/x.safetensors`` where runs/ is new)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def set_threads(n: int) -> None:
    """Cap torch's CPU threads at ``n`` (0: torch's default)."""
    import torch

    if n > 0:
        torch.set_num_threads(n)
