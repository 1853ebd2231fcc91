"""Evaluation runs, as the CLI (``tactus eval``, ``tactus baseline``) asks for them: load and
gate the data, score one or more checkpoints on one scope and aggregate the runs, and train
the STAG baseline then score its held-out recordings. The CLI only parses and prints."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tactus_memory.errors import InvalidInputError
from tactus_memory.training.evaluate import (
    DEFAULT_VOTES,
    EVAL_SEED,
    EvalResult,
    EvalSet,
    Scorer,
    analyse,
    evaluate_scorer,
    file_fingerprint,
    select_eval_frames,
    tactus_scorer,
)
from tactus_memory.training.metrics import SCALAR_METRICS, aggregate_runs

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space

log = logging.getLogger(__name__)

#: the held-out metrics a baseline checkpoint records about itself
HELDOUT_KEYS = (
    "n_tuples",
    "n_recordings",
    "top1",
    "top3",
    "top1_vote",
    "top3_vote",
    "recording_top1",
)


def load_eval_data(paths: list[Path], profile: Any = None) -> tuple[Any, list[dict[str, Any]]]:
    """Load each file (fingerprinted; STAG or ``.npz``, whose frames ``profile`` checks),
    combine, run the dynamic-range gate per subset under ``profile`` (default STAG_GLOVE)."""
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.training.data import combine, load_stag
    from tactus_memory.training.npz_io import load_npz

    parts = [load_npz(p, profile) if str(p).endswith(".npz") else load_stag(p) for p in paths]
    fps = [file_fingerprint(d, p) for d, p in zip(parts, paths, strict=True)]
    data = parts[0] if len(parts) == 1 else combine(parts)
    data.check_dynamic_range(STAG_GLOVE if profile is None else profile)
    return data, fps


def checkpoint_profile(spec: str) -> Any:
    """The sensor profile a Tactus checkpoint records (None for other checkpoints)."""
    from tactus_memory.touch.checkpoint import read_metadata
    from tactus_memory.touch.profile import SensorProfile

    try:
        calibration = read_metadata(resolve_checkpoint(spec)).get("calibration")
    except (ValueError, FileNotFoundError):
        return None
    return SensorProfile.from_dict(calibration) if calibration else None


def run_eval(
    checkpoints: list[str],
    data_paths: list[Path],
    *,
    split: str = "test",
    holdout: str | None = None,
    votes: int = 4,
    seed: int | None = None,
    analysis: bool = True,
    progress: bool = True,
    warn: Callable[[str], None] = log.warning,
    space: Any = None,
    loaded: tuple[Any, Any] | None = None,
    profile: Any = None,
) -> tuple[dict[str, Any], Any, Any]:
    """Evaluate one or more checkpoints on one scope. Returns (payload, first result, scope).

    One checkpoint: the payload is that run's metrics. Several: ``runs`` (each run's metrics),
    ``aggregate`` (mean, sample std per metric), and the top-level metric keys hold the means.
    ``warn`` hears about checkpoints whose training data overlaps the scored recordings.
    ``space``: a ``SpaceChoice`` for the analyses' text space (each checkpoint's recorded
    space, its model folder from ``--space-path``); None: built from the name when possible.
    ``loaded``: what ``load_eval_data(data_paths)`` returned, when the caller has it already.
    ``profile``: the sensor profile calibrating the frames (default STAG_GLOVE).
    """
    data, fps = loaded if loaded is not None else load_eval_data(data_paths, profile)
    cal = None if profile is None else data.calibrated(profile)
    es = select_eval_frames(data, split, holdout, fingerprints=fps, calibrated=cal)
    runs, first = [], None
    for spec in checkpoints:
        path = resolve_checkpoint(spec)
        m, res, _ = evaluate_checkpoint(
            path,
            es,
            votes=votes,
            seed=EVAL_SEED if seed is None else seed,
            analysis=analysis,
            progress=progress,
            space="auto" if space is None or not analysis else checkpoint_space(path, space),
        )
        runs.append(m)
        first = first or res
        if m["leakage"]["status"] == "overlap":
            warn(
                f"WARNING: {path}: {m['leakage']['trained_on']} of the "
                f"{m['leakage']['scored_recordings']} scored recordings were in its training "
                f"data (e.g. {m['leakage']['examples']}); these scores are not held-out"
            )
    if len(runs) == 1:
        return runs[0], first, es
    agg = aggregate_runs(runs)
    shared = (
        "split",
        "k",
        "seed",
        "votes",
        "n_tuples",
        "n_recordings",
        "n_frames",
        "chance",
        "chance_top3",
        "classes",
        "data",
        "model_kind",
    )
    payload: dict[str, Any] = {k: runs[0][k] for k in shared}
    payload.update({k: agg[k]["mean"] for k in SCALAR_METRICS})
    payload.update({f"{k}_std": agg[k]["std"] for k in SCALAR_METRICS})
    payload["n_runs"] = len(runs)
    payload["checkpoint"] = [r["checkpoint"] for r in runs]
    payload["aggregate"] = agg
    payload["runs"] = runs
    return payload, first, es


def train_baseline_run(
    data: list[Path], out: Path, holdout: str, cfg: Any
) -> tuple[str, dict[str, Any]]:
    """Train the STAG reference CNN (``cfg``: a ``BaselineConfig``) on the non-held-out frames,
    saving the latest epoch as it goes (no model selection); with a holdout, score the held-out
    recordings. Returns (the checkpoint's sha256, its metadata)."""
    from tactus_memory.training.baseline import (
        BaselineScorer,
        baseline_meta,
        save_baseline,
        train_baseline,
    )
    from tactus_memory.training.train import holdout_recordings, prepare_data

    d, fps = load_eval_data(data)
    td = prepare_data(d, holdout_recordings(d, holdout))

    def snapshot(net: Any, summary: dict[str, Any]) -> None:  # latest epoch, never selected
        meta = baseline_meta(td, cfg, summary, holdout)
        save_baseline(out, net, dict(meta, data=fps, complete=False))

    net, summary = train_baseline(td, cfg, on_epoch=snapshot)
    meta = baseline_meta(td, cfg, summary, holdout)
    meta["data"] = fps
    meta["complete"] = True
    if holdout != "none":
        es = select_eval_frames(d, holdout=holdout, calibrated=td.calibrated, fingerprints=fps)
        res = evaluate_scorer(BaselineScorer(net, td.classes), es)
        meta["heldout"] = {k: res.metrics[k] for k in HELDOUT_KEYS}
    return save_baseline(out, net, meta), meta


# --------------------------------------------------------------------------- checkpoints


def checkpoint_space(path: Path, choice: Any) -> Any:
    """The text space a Tactus checkpoint was trained in, built from the space options and
    checked against the checkpoint's record (name, dim, model fingerprint); raises
    ``SpaceConfigError`` (one line) when it cannot be. Other checkpoints (the baseline) get
    ``"auto"``."""
    from tactus_memory.spaces.resolve import resolve_space
    from tactus_memory.touch.checkpoint import read_metadata

    try:
        recorded = read_metadata(path)["space"]
    except (ValueError, KeyError):
        return "auto"
    return resolve_space(choice, recorded, owner=f"checkpoint {Path(path).name}")


def resolve_checkpoint(spec: str | Path) -> Path:
    from tactus_memory.touch.checkpoint import default_checkpoint_path

    p = default_checkpoint_path() if str(spec) == "default" else Path(spec)
    if not p.is_file():
        raise FileNotFoundError(f"checkpoint not found: {p}")
    return p


def load_scorer(path: str | Path, device: str = "cpu") -> tuple[Scorer, dict[str, Any]]:
    """A Tactus or baseline checkpoint -> (scorer, provenance), by its embedded metadata."""
    from safetensors import safe_open

    from tactus_memory.hashing import file_sha256
    from tactus_memory.touch.checkpoint import load_checkpoint

    with safe_open(str(path), framework="pt") as f:
        md = f.metadata() or {}
    if "tactus" in md:
        ckpt = load_checkpoint(path, device=device)
        info = {
            "path": str(path),
            "sha256": ckpt.sha256,
            "kind": "tactus",
            "model": ckpt.meta.get("model", {}).get("name"),
            "space": ckpt.meta.get("space"),
            "steps": ckpt.meta.get("steps"),
            "seed": ckpt.meta.get("seed"),
            "train_holdout": ckpt.meta.get("train_args", {}).get("holdout"),
            "train_data_fingerprint": ckpt.meta.get("data_fingerprint"),
            "train_heldout_recordings": (
                ckpt.meta.get("metrics", {}).get("heldout", {}).get("recordings_named", [])
            ),
        }
        return tactus_scorer(ckpt, device=device), info
    from tactus_memory.training.baseline import BASELINE_META_KEY, load_baseline

    if BASELINE_META_KEY in md:
        net, meta = load_baseline(path, device=device)
        from tactus_memory.training.baseline import BaselineScorer

        info = {
            "path": str(path),
            "sha256": file_sha256(path),
            "kind": "baseline",
            "model": "stag-cnn",
            "epochs": meta.get("epochs"),
            "seed": meta.get("seed"),
            "train_holdout": meta.get("holdout"),
            "train_data_fingerprint": meta.get("data_fingerprint"),
            "train_heldout_recordings": meta.get("heldout_recordings", []),
        }
        return BaselineScorer(net, list(meta["classes"]), device=device), info
    raise InvalidInputError(f"{path}: neither a Tactus nor a baseline checkpoint")


def leakage_check(info: dict[str, Any], es: EvalSet) -> dict[str, Any]:
    """Were the scored recordings in the checkpoint's training data?

    Decidable when the checkpoint records the fingerprint of its training data and it equals
    the evaluated data's (same files, same order): then every scored recording that the
    training run did not hold out was trained on. Otherwise ``unknown``.
    """
    names = es.recording_names()
    train_fp = info.get("train_data_fingerprint")
    if not train_fp or not es.fingerprint or train_fp != es.fingerprint:
        return {"status": "unknown", "reason": "training data fingerprint differs or is absent"}
    held = set(info.get("train_heldout_recordings") or [])
    overlap = [n for n in names if n not in held]
    return {
        "status": "overlap" if overlap else "clean",
        "scored_recordings": len(names),
        "trained_on": len(overlap),
        "examples": overlap[:5],
    }


def space_for(scorer: Scorer) -> Space | None:
    """The checkpoint's text space when it can be built here (None otherwise)."""
    name = getattr(scorer, "space_name", None)
    if not name:
        return None
    try:  # a Qwen3-VL checkpoint's space needs TACTUS_SPACE_PATH (or eval --space-path)
        from tactus_memory.spaces.resolve import SpaceChoice, resolve_space

        return resolve_space(SpaceChoice(name=name))
    except Exception:  # unknown or unavailable space: the phrasing test is skipped
        return None


def evaluate_checkpoint(
    path: str | Path,
    es: EvalSet,
    *,
    votes: int = DEFAULT_VOTES,
    seed: int = EVAL_SEED,
    analysis: bool = True,
    space: Space | None | str = "auto",
    progress: bool = True,
    device: str = "cpu",
) -> tuple[dict[str, Any], EvalResult, Scorer]:
    """Load, score, analyse. Returns (JSON metrics, raw result, scorer)."""
    scorer, info = load_scorer(path, device=device)
    res = evaluate_scorer(scorer, es, votes=votes, seed=seed, progress=progress)
    m = dict(res.metrics)
    m["checkpoint"] = info
    m["leakage"] = leakage_check(info, es)
    if analysis:
        sp = space_for(scorer) if isinstance(space, str) else space
        m["analysis"] = analyse(res, scorer, space=sp)
    return m, res, scorer
