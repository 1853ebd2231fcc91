"""Evaluation of touch models on STAG: the paper's tables and analyses.

Protocol (paper, Method "Evaluation"; stag-format.md "Reference sampling"):

- **Scope.** ``select_eval_frames``: the valid frames (``hasValidLabel``, or ``graspValid``
  for the weights subset) of the chosen split. ``split="test"`` keeps each file's 'test'
  frames; a file without a split field (``weights``) is scored whole. ``split="all"`` keeps
  every valid frame. A ``holdout`` spec (the same grammar as ``tactus train --holdout``,
  :func:`tactus_memory.training.train.holdout_recordings`) restricts scoring to exactly the
  recordings that training run held out (all their valid frames, whatever the split), so a
  validation run is re-scored on the same frames its own summary used.
- **Tuples.** Anchors are scope frames that are ``isBalanced``; each anchor gets one cluster
  tuple (:class:`TupleSampler`, clusters and tiling seeded with ``seed``; the default
  ``EVAL_SEED`` matches ``train.evaluate``). ``top1``/``top3`` score this one fixed draw.
- **Voting.** ``top1_vote``/``top3_vote``: the embeddings of ``votes`` independent draws (draw
  0 is the fixed draw above, draw v>0 uses ``default_rng([seed, v])``) are pooled before
  ranking. For Tactus pooling is the mean of the unit embeddings, renormalised; for the
  supervised baseline it is the mean of the class probabilities.
- **Recording level.** ``recording_top1``: per recording, up to ``RECORDING_POOL`` (64) of
  its valid scope frames, evenly spaced in recording order when there are more, are tiled
  in order into consecutive K-frame windows (the last window padded by repeating its last
  frame, exactly as the model pads); the window embeddings are pooled as for voting and
  ranked once. A recording with fewer valid frames than K is one padded window, so it
  still counts. No sampling is involved (the paper's protocol-independent anchor).
- **K-sweep.** Inference-time only: the first n frames of each fixed tuple (anchor first),
  padded to K by repeating the last one, for n in (1, 2, 4, 8).
- **Analysis** (paper Sec. "What the Released Model Gets Wrong"): computed, like the paper,
  on the voted embeddings. The Spearman correlation between per-pair confusion rates and
  text-target cosine runs over all ordered class pairs (27 * 26 = 702), with uncentred
  (template-averaged raw) and centred targets. Phrasing robustness re-ranks the same voted
  embeddings against six target constructions (template ensemble, single template, bare
  names; each centred and uncentred) built through ``targets.py`` in the checkpoint's space.

Everything model-specific hides behind a :class:`Scorer` (embed windows, pool embeddings,
score against classes), so Tactus and the baseline share one code path and one JSON shape.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from tqdm.auto import tqdm

from tactus_memory.errors import InvalidInputError
from tactus_memory.hashing import file_sha256
from tactus_memory.touch.targets import centre, natural_name
from tactus_memory.training.tuples import TupleSampler

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space
    from tactus_memory.touch.checkpoint import Checkpoint
    from tactus_memory.training.data import StagData

from tactus_memory.training.metrics import (
    KSWEEP,
    RECORDING_POOL,
    _nan_to_none,
    confusion_counts,
    ksweep_windows,
    mean_unit,
    per_class_topk,
    predictions,
    recording_windows,
    row_normalise,
    text_confusion_correlation,
    top_confusions,
    topk_accuracy,
    unit_rows,
)

EVAL_SEED = 1234  # same fixed tiling seed as tactus_memory.training.train.EVAL_SEED
DEFAULT_VOTES = 4  # paper: tuple voting over four draws
CONFUSION_LABEL_MIN = 0.08  # paper Fig. confusion: off-diagonal cells >= 0.08 are labelled


# --------------------------------------------------------------------------- scope


@dataclass
class EvalSet:
    """The frames a model is scored on. Arrays have length N (all frames of the data)."""

    calibrated: np.ndarray  # (N, 32, 32) float32 in [0, 1]
    labels: np.ndarray  # (N,) int64 class index
    recording_id: np.ndarray  # (N,) int64
    members: np.ndarray  # (N,) bool: valid frames in scope (tuple members, recording pools)
    anchors: np.ndarray  # (N,) bool: members that are isBalanced (one tuple each)
    classes: list[str]
    recordings: list[str]  # names indexed by recording id
    split: str  # "test" | "all" | "holdout:<spec>"
    data: list[dict[str, Any]] = field(default_factory=list)  # per-file fingerprints
    fingerprint: str = ""  # StagData.fingerprint() of the (combined) data, as train records it

    def recording_names(self) -> list[str]:
        ids = np.unique(self.recording_id[self.members])
        return [self.recordings[int(r)] if int(r) < len(self.recordings) else str(r) for r in ids]

    @property
    def n_recordings(self) -> int:
        return int(np.unique(self.recording_id[self.members]).size)


def file_fingerprint(data: StagData, path: str | Path | None = None) -> dict[str, Any]:
    """Identity of one loaded file: content fingerprint plus the file's own sha256."""
    out: dict[str, Any] = {
        "source": data.sources[0] if data.sources else "",
        "fingerprint": data.fingerprint(),
        "frames": data.n_frames,
        "valid_frames": data.valid_frames,
        "recordings": data.n_recordings,
        "splits": list(data.splits),
    }
    p = Path(path) if path is not None else Path(out["source"])
    if p.is_dir():
        p = p / "metadata.mat"
    if p.is_file():
        out["file_sha256"] = file_sha256(p)
    return out


def scope_mask(data: StagData, split: str = "test", holdout: Sequence[int] | None = None):
    """(N,) bool valid frames in scope; see the module docstring."""
    if holdout is not None:
        return data.valid & np.isin(data.recording_id, np.asarray(list(holdout), np.int64))
    if split == "all":
        return data.valid.copy()
    if split not in ("test", "train"):
        return data.valid_mask(split)
    return data.valid & (data.split_mask(split) | (data.split_id == -1))


def select_eval_frames(
    data: StagData,
    split: str = "test",
    holdout: str | None = None,
    *,
    fingerprints: list[dict[str, Any]] | None = None,
    calibrated: np.ndarray | None = None,
) -> EvalSet:
    """The scope of an evaluation on loaded (possibly combined) STAG data.

    ``holdout``: a ``tactus train --holdout`` spec; when given (and not ``none``) it replaces
    the split. ``calibrated``: precomputed (N, 32, 32) frames (default: the STAG_GLOVE affine).
    """
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.training.train import holdout_recordings

    held = None
    label = split
    if holdout and holdout.strip() != "none":
        held = holdout_recordings(data, holdout)
        label = f"holdout:{holdout}"
    members = scope_mask(data, split, held)
    if not members.any():
        raise InvalidInputError(f"no valid frames to evaluate for split={label!r}")
    cal = data.calibrated(STAG_GLOVE) if calibrated is None else calibrated
    return EvalSet(
        calibrated=cal,
        labels=np.asarray(data.object_id, np.int64),
        recording_id=np.asarray(data.recording_id, np.int64),
        members=members,
        anchors=members & data.balanced,
        classes=list(data.objects),
        recordings=list(data.recordings),
        split=label,
        data=fingerprints or [],
        fingerprint=data.fingerprint(),
    )


# --------------------------------------------------------------------------- scorers


class Scorer(Protocol):
    """What evaluation needs from a model."""

    k: int  # frames per window
    classes: list[str]
    kind: str  # "tactus" | "baseline" | ...

    def embed(self, windows: np.ndarray) -> np.ndarray:
        """(B, k, 32, 32) calibrated windows -> (B, D) embeddings."""
        ...

    def pool(self, embs: np.ndarray) -> np.ndarray:
        """(V, B, D) -> (B, D): combine V embeddings of the same item (votes, windows)."""
        ...

    def scores(self, emb: np.ndarray) -> np.ndarray:
        """(B, D) -> (B, C) class scores (higher is better)."""
        ...


@dataclass
class EmbeddingScorer:
    """Cosine ranking of unit embeddings against (C, D) unit class targets (Tactus).

    ``embed_fn`` maps (B, k, 32, 32) windows to (B, D) unit rows; tests pass plain functions.
    """

    embed_fn: Callable[[np.ndarray], np.ndarray]
    targets: np.ndarray  # (C, D) the rows logits were trained against (centred)
    classes: list[str]
    k: int = 8
    kind: str = "tactus"
    raw_targets: np.ndarray | None = None  # (C, D) uncentred, for the Spearman analysis
    space_name: str | None = None

    def embed(self, windows: np.ndarray) -> np.ndarray:
        return np.asarray(self.embed_fn(windows), dtype=np.float32)

    def pool(self, embs: np.ndarray) -> np.ndarray:
        return mean_unit(embs, axis=0)

    def scores(self, emb: np.ndarray) -> np.ndarray:
        return unit_rows(emb) @ unit_rows(self.targets).T


def tactus_scorer(ckpt: Checkpoint, batch: int = 256, device: str = "cpu") -> EmbeddingScorer:
    """A loaded Tactus checkpoint as a scorer (centred targets, as in training)."""
    from tactus_memory.training.train import embed_windows

    model = ckpt.model

    def fn(windows: np.ndarray) -> np.ndarray:
        return embed_windows(model, windows, batch=batch, device=device)

    return EmbeddingScorer(
        embed_fn=fn,
        targets=ckpt.targets.centred,
        classes=ckpt.classes,
        k=int(model.cfg.frames),
        raw_targets=ckpt.targets.raw,
        space_name=ckpt.space_name,
    )


# --------------------------------------------------------------------------- evaluation


@dataclass
class EvalResult:
    metrics: dict[str, Any]  # the JSON-able summary
    tuples: np.ndarray  # (T, K) the fixed draw
    y: np.ndarray  # (T,) true classes of the tuples
    emb: np.ndarray  # (T, D) single-draw embeddings
    emb_vote: np.ndarray  # (T, D) voted embeddings
    scores: np.ndarray  # (T, C) single draw
    scores_vote: np.ndarray  # (T, C)


def _embed_batched(scorer: Scorer, es: EvalSet, idx: np.ndarray, chunk: int = 512) -> np.ndarray:
    outs = [scorer.embed(es.calibrated[idx[s : s + chunk]]) for s in range(0, len(idx), chunk)]
    return np.concatenate(outs) if outs else np.zeros((0, 0), np.float32)


def evaluate_scorer(
    scorer: Scorer,
    es: EvalSet,
    *,
    votes: int = DEFAULT_VOTES,
    seed: int = EVAL_SEED,
    ksweep: Sequence[int] = KSWEEP,
    pool: int = RECORDING_POOL,
    progress: bool = True,
) -> EvalResult:
    """Every metric of the module docstring for one scorer on one scope."""
    if list(scorer.classes) != list(es.classes):
        raise InvalidInputError(
            f"model classes {scorer.classes} differ from the data's classes {es.classes}"
        )
    if votes < 1:
        raise InvalidInputError(f"votes must be >= 1, got {votes}")
    k, n_cls = int(scorer.k), len(es.classes)
    sampler = TupleSampler(
        es.calibrated, es.recording_id, es.members, anchors=es.anchors, k=k, seed=seed
    )
    steps = votes + len([n for n in ksweep if n < k]) + 1
    bar = tqdm(total=steps, desc=f"eval {scorer.kind}", disable=not progress, leave=False)
    tuples = sampler.fixed(seed)  # (T, K)
    y = es.labels[tuples[:, 0]] if len(tuples) else np.zeros(0, np.int64)
    draws = [tuples] + [sampler.sample(np.random.default_rng([seed, v])) for v in range(1, votes)]
    embs = []
    for d in draws:
        embs.append(_embed_batched(scorer, es, d))
        bar.update(1)
    emb = embs[0]
    emb_vote = scorer.pool(np.stack(embs)) if len(tuples) else emb
    sc = scorer.scores(emb) if len(tuples) else np.zeros((0, n_cls))
    sc_vote = scorer.scores(emb_vote) if len(tuples) else np.zeros((0, n_cls))

    # K-sweep on the fixed draw
    sweep: dict[str, float | None] = {}
    for n in ksweep:
        if n > k:
            continue
        if n == k:
            sweep[str(n)] = _nan_to_none(topk_accuracy(sc, y, 1)) if len(y) else None
            continue
        if len(tuples):
            e = _embed_batched(scorer, es, ksweep_windows(tuples, n))
            sweep[str(n)] = _nan_to_none(topk_accuracy(scorer.scores(e), y, 1))
        else:
            sweep[str(n)] = None
        bar.update(1)

    # recording level
    rec_ids = np.unique(es.recording_id[es.members])
    per_rec: list[dict[str, Any]] = []
    for r in rec_ids:
        fr = np.flatnonzero(es.members & (es.recording_id == r))
        wins = recording_windows(fr, k, pool)  # (W, K)
        pooled = scorer.pool(scorer.embed(es.calibrated[wins])[:, None, :])  # (W,1,D) -> (1,D)
        s = scorer.scores(pooled)[0]  # (C,)
        true = int(es.labels[fr[0]])
        per_rec.append(
            {
                "recording": es.recordings[int(r)] if int(r) < len(es.recordings) else str(r),
                "recording_id": int(r),
                "true": true,
                "pred": int(np.argmax(s)),
                "true_rank": int((s > s[true]).sum()) + 1,
                "frames": int(min(fr.size, pool)),
                "windows": int(len(wins)),
                "tuples": int(np.isin(tuples[:, 0], fr).sum()) if len(tuples) else 0,
            }
        )
    bar.update(1)
    bar.close()
    rec_true = np.array([p["true"] for p in per_rec], np.int64)
    rec_pred = np.array([p["pred"] for p in per_rec], np.int64)

    conf_counts = confusion_counts(y, predictions(sc), n_cls)
    conf_vote = confusion_counts(y, predictions(sc_vote), n_cls)
    values, counts = np.unique(y, return_counts=True)
    metrics: dict[str, Any] = {
        "model_kind": scorer.kind,
        "split": es.split,
        "k": k,
        "seed": int(seed),
        "votes": int(votes),
        "n_tuples": int(len(y)),
        "n_recordings": int(len(rec_ids)),
        "n_frames": int(es.members.sum()),
        "top1": _nan_to_none(topk_accuracy(sc, y, 1)),
        "top3": _nan_to_none(topk_accuracy(sc, y, 3)),
        "top1_vote": _nan_to_none(topk_accuracy(sc_vote, y, 1)),
        "top3_vote": _nan_to_none(topk_accuracy(sc_vote, y, 3)),
        "recording_top1": float((rec_true == rec_pred).mean()) if len(rec_true) else None,
        "chance": 1.0 / n_cls,
        "chance_top3": min(1.0, 3.0 / n_cls),
        "majority_rate": float(counts.max() / counts.sum()) if counts.size else None,
        "classes": list(es.classes),
        "per_class": per_class_topk(sc, y, es.classes, 1),
        "per_class_top3": per_class_topk(sc, y, es.classes, 3),
        "per_class_vote": per_class_topk(sc_vote, y, es.classes, 1),
        "per_class_tuples": {
            es.classes[int(c)]: int(n) for c, n in zip(values, counts, strict=True)
        },
        "confusion": row_normalise(conf_counts).round(6).tolist(),
        "confusion_counts": conf_counts.tolist(),
        "confusion_vote": row_normalise(conf_vote).round(6).tolist(),
        "ksweep": sweep,
        "per_recording": per_rec,
        "data": es.data,
    }
    return EvalResult(metrics, tuples, y, emb, emb_vote, sc, sc_vote)


# --------------------------------------------------------------------------- analysis


TARGET_CONSTRUCTIONS = (
    "ensemble_centred",
    "ensemble_uncentred",
    "single_centred",
    "single_uncentred",
    "bare_centred",
    "bare_uncentred",
)


def target_constructions(space: Space, classes: Sequence[str]) -> dict[str, np.ndarray]:
    """The six (C, D) target sets of the paper's phrasing test, through ``targets.py``:
    template ensemble (every template, averaged), single template (the display phrase),
    bare names (``natural_name``: "mug", "screwdriver"); each centred and uncentred."""
    from tactus_memory.touch.targets import build_targets

    ens = build_targets(space, classes, ensemble=True)
    single = build_targets(space, classes, ensemble=False)
    bare_raw = unit_rows(space.embed_texts([natural_name(c) for c in classes], query=False))
    return {
        "ensemble_centred": ens.centred,
        "ensemble_uncentred": ens.raw,
        "single_centred": single.centred,
        "single_uncentred": single.raw,
        "bare_centred": centre(bare_raw, bare_raw.mean(axis=0)),
        "bare_uncentred": bare_raw,
    }


def phrasing_robustness(
    emb: np.ndarray, y: np.ndarray, constructions: dict[str, np.ndarray]
) -> dict[str, dict[str, float | None]]:
    """Top-1/top-3 of the same (T, D) embeddings ranked against each target construction."""
    out = {}
    for name, t in constructions.items():
        s = unit_rows(emb) @ unit_rows(t).T
        out[name] = {
            "top1": _nan_to_none(topk_accuracy(s, y, 1)),
            "top3": _nan_to_none(topk_accuracy(s, y, 3)),
        }
    return out


def analyse(
    result: EvalResult,
    scorer: Scorer,
    *,
    space: Space | None = None,
) -> dict[str, Any]:
    """Confusion structure, text-geometry correlation and phrasing robustness (voted draws).

    Text analyses need a text-target scorer (:class:`EmbeddingScorer`); the phrasing test also
    needs ``space`` (the checkpoint's text space); each part is skipped with a note otherwise.
    """
    m = result.metrics
    classes = m["classes"]
    conf_vote = np.asarray(m["confusion_vote"])
    out: dict[str, Any] = {
        "protocol": f"tuple voting over {m['votes']} draws",
        "top_confusions": top_confusions(conf_vote, classes, 10, min_rate=0.0),
        "classes_ge_0.80": int(
            sum(1 for v in m["per_class_vote"].values() if v is not None and v >= 0.80)
        ),
        "classes_ge_0.99": int(
            sum(1 for v in m["per_class_vote"].values() if v is not None and v >= 0.99)
        ),
        "classes_scored": int(sum(1 for v in m["per_class_vote"].values() if v is not None)),
        "notes": [],
    }
    raw = getattr(scorer, "raw_targets", None)
    cen = getattr(scorer, "targets", None)
    if raw is None or cen is None:
        out["notes"].append("no text targets (closed-set model): text analyses skipped")
        return out
    out["spearman"] = text_confusion_correlation(conf_vote, raw, cen)
    out["spearman_single_draw"] = text_confusion_correlation(np.asarray(m["confusion"]), raw, cen)
    cos_raw = unit_rows(raw) @ unit_rows(raw).T
    idx = {c: i for i, c in enumerate(classes)}
    out["pair_text_cosine"] = [
        dict(row, cos_uncentred=float(cos_raw[idx[row["true"]], idx[row["pred"]]]))
        for row in out["top_confusions"]
    ]
    if space is None:
        out["notes"].append("text space unavailable: phrasing robustness skipped")
        return out
    cons = target_constructions(space, classes)
    out["phrasing"] = phrasing_robustness(result.emb_vote, result.y, cons)
    out["phrasing_single_draw"] = phrasing_robustness(result.emb, result.y, cons)
    out["stored_vs_rebuilt_targets_max_abs"] = float(
        np.abs(unit_rows(cons["ensemble_centred"]) - unit_rows(cen)).max()
    )
    return out
