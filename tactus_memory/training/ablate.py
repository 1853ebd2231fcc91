"""Recipe ablations (paper Table "Recipe ladder", the three data-path levers), one command.

Rows, each changing ONE thing of the recipe, everything else fixed (model, steps, batch,
held-out recordings, targets, seeds):

==============  ==============================  ===============  ==================
row             input normalisation             tuples           trunk init
==============  ==============================  ===============  ==================
recipe          calibration affine              cluster          MAE (same norm.)
max_scaling     per-file max scaling (defect)   cluster          MAE (same norm.)
random_tuples   calibration affine              random           MAE
no_mae          calibration affine              cluster          random init
==============  ==============================  ===============  ==================

``max_scaling`` divides each file's raw readings by that file's maximum (the paper's silent
defect: the resting pedestal survives and the weights subset lands on another scale). The MAE
trunk of a row is pretrained on frames normalised the way that row normalises them, so the
row really differs in normalisation only. MAE trunks are pretrained once per (normalisation,
seed), on every frame of the files except the held-out recordings.

Training reuses ``train.fit`` unchanged; the normalisation switch is implemented here by
handing ``fit`` a ``TrainData`` whose ``calibrated`` frames are max-scaled (``fit`` has no
normalisation hook; none is needed since it takes the frames as given). Scores are ``fit``'s
own held-out evaluation (fixed-seed cluster tuples, top-1/top-3, recording top-1).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.training.metrics import mean_std

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space

ROWS: dict[str, dict[str, Any]] = {
    "recipe": {"norm": "affine", "sampling": "cluster", "mae": True},
    "max_scaling": {"norm": "max", "sampling": "cluster", "mae": True},
    "random_tuples": {"norm": "affine", "sampling": "random", "mae": True},
    "no_mae": {"norm": "affine", "sampling": "cluster", "mae": False},
}
METRICS = ("top1", "top3", "recording_top1")


@dataclass
class AblationConfig:
    steps: int = 300
    pretrain_steps: int = 300
    seeds: int = 2
    holdout: str = "one-per-object@blindfolded"
    model: str = "tactus-lite"
    batch: int = 64
    pretrain_batch: int = 256
    space: str = "minilm"
    rows: list[str] = field(default_factory=lambda: list(ROWS))


def per_file_max_scaled(pressure: np.ndarray, subset: np.ndarray) -> np.ndarray:
    """(N, 32, 32) raw -> float32 raw / max(raw of the same file): the defective scaling."""
    out = np.empty(pressure.shape, np.float32)
    for s in np.unique(subset):
        m = subset == s
        top = float(pressure[m].max())
        out[m] = pressure[m].astype(np.float32) / (top if top > 0 else 1.0)
    return np.clip(out, 0.0, 1.0)


def run_ablation(
    data_paths: Sequence[str | Path],
    cfg: AblationConfig,
    workdir: str | Path,
    *,
    space: Space | None = None,
    progress: bool = True,
    on_run: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Train every (row, seed); returns per-run scores and mean ± sample std per row.

    ``space``: the text space object (default: ``get_space(cfg.space)``); ``on_run(partial)``
    receives the result so far after every run (the CLI writes it, so a cut-off run keeps
    what finished)."""
    from tactus_memory.spaces import get_space
    from tactus_memory.touch.targets import build_targets
    from tactus_memory.training.pretrain import PretrainConfig, pretrain, recipe_warmup
    from tactus_memory.training.train import (
        TrainConfig,
        fit,
        holdout_recordings,
        load_data,
        prepare_data,
    )

    unknown = [r for r in cfg.rows if r not in ROWS]
    if unknown:
        raise ValueError(f"unknown ablation rows {unknown}; known: {list(ROWS)}")
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    data = load_data(data_paths)
    held = holdout_recordings(data, cfg.holdout)
    td_affine = prepare_data(data, held)
    frames = {
        "affine": td_affine,
        "max": replace(
            td_affine,
            calibrated=per_file_max_scaled(data.pressure, data.subset),
            calibration={"name": "per-file-max", "note": "raw / max(raw of the file)"},
        ),
    }
    space = space if space is not None else get_space(cfg.space)
    targets = build_targets(space, td_affine.classes)

    maes: dict[tuple[str, int], Path] = {}
    runs: list[dict[str, Any]] = []
    for seed in range(cfg.seeds):
        for row in cfg.rows:
            spec = ROWS[row]
            td = frames[spec["norm"]]
            both = {"model": cfg.model, "seed": seed}  # pretraining and training alike
            mae_path = None
            if spec["mae"]:
                key = (spec["norm"], seed)
                if key not in maes:
                    p = work / f"mae_{spec['norm']}_s{seed}.safetensors"
                    pretrain(
                        td.calibrated,
                        td.recording_id,
                        held,
                        p,
                        PretrainConfig(
                            steps=cfg.pretrain_steps,
                            batch=cfg.pretrain_batch,
                            warmup=recipe_warmup(cfg.pretrain_steps),
                            **both,
                        ),
                        fingerprint=td.fingerprint,
                        progress=progress,
                    )
                    maes[key] = p
                mae_path = maes[key]
            t0 = time.perf_counter()
            summary = fit(
                td,
                targets,
                TrainConfig(
                    steps=cfg.steps,
                    batch=cfg.batch,
                    **both,
                    sampling=spec["sampling"],
                    warmup=recipe_warmup(cfg.steps),
                    save_every=max(cfg.steps, 1),
                ),
                work / f"{row}_s{seed}.safetensors",
                space_dim=space.dim,
                pretrained=mae_path,
                device="cpu",
                progress=progress,
            )
            ho = summary.get("heldout", {})
            runs.append(
                {
                    "row": row,
                    "seed": seed,
                    **spec,
                    **{k: ho.get(k) for k in METRICS},
                    "n_tuples": ho.get("tuples"),
                    "wall_s": round(time.perf_counter() - t0, 1),
                }
            )
            if on_run is not None:
                on_run(_result(cfg, data_paths, space, data, held, runs))
    return _result(cfg, data_paths, space, data, held, runs)


def _result(
    cfg: AblationConfig,
    data_paths: Sequence[str | Path],
    space: Space,
    data: Any,
    held: list[int],
    runs: list[dict[str, Any]],
) -> dict[str, Any]:
    table = {
        row: {
            "changes": ROWS[row],
            **{k: mean_std([r[k] for r in runs if r["row"] == row]) for k in METRICS},
        }
        for row in cfg.rows
        if any(r["row"] == row for r in runs)
    }
    return {
        "config": {**cfg.__dict__, "data": [str(p) for p in data_paths], "space": space.name},
        "heldout_recordings": [data.recordings[r] for r in held],
        "rows": table,
        "runs": runs,
    }


def format_table(result: dict[str, Any]) -> str:
    """Markdown table: one row per ablation, mean ± sample std per metric."""
    lines = ["| row | " + " | ".join(METRICS) + " |", "|---" * (len(METRICS) + 1) + "|"]
    for row, v in result["rows"].items():
        cells = []
        for k in METRICS:
            m, s = v[k]["mean"], v[k]["std"]
            cells.append("–" if m is None else f"{m:.3f}" + ("" if s is None else f" ± {s:.3f}"))
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
