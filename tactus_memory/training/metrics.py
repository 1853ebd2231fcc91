"""Evaluation metrics, pure functions over arrays: top-k accuracy, confusion, per-class
accuracy, window tiling, the confusion-vs-text-similarity correlation, run aggregation.
:mod:`tactus_memory.training.evaluate` scores checkpoints with them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import InvalidInputError

if TYPE_CHECKING:
    pass


KSWEEP = (1, 2, 4, 8)  # paper Fig. ksweep: distinct frames per window
RECORDING_POOL = 64  # paper, Evaluation: up to 64 valid frames pooled per recording
SCALAR_METRICS = (
    "top1",
    "top3",
    "top1_vote",
    "top3_vote",
    "recording_top1",
)


# --------------------------------------------------------------------------- metrics


def topk_accuracy(scores: np.ndarray, y: np.ndarray, k: int) -> float:
    """scores (T, C), y (T,) -> fraction of rows whose true class is among the k highest.

    Ties are broken by class index (stable sort), so a constant scorer predicts class 0.
    """
    s, yy = np.asarray(scores), np.asarray(y).reshape(-1)
    if s.ndim != 2 or s.shape[0] != yy.shape[0]:
        raise InvalidInputError(f"scores must be (T, C) with T = len(y); got {s.shape}, {yy.shape}")
    if yy.size == 0:
        return float("nan")
    top = np.argsort(-s, axis=1, kind="stable")[:, :k]
    return float((top == yy[:, None]).any(axis=1).mean())


def predictions(scores: np.ndarray) -> np.ndarray:
    """(T, C) -> (T,) argmax (first index on ties)."""
    return np.argmax(np.asarray(scores), axis=1).astype(np.int64)


def confusion_counts(y_true: np.ndarray, y_pred: np.ndarray, n_classes: int) -> np.ndarray:
    """(C, C) int64 counts, rows = true class, columns = predicted class."""
    m = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(m, (np.asarray(y_true, np.int64), np.asarray(y_pred, np.int64)), 1)
    return m


def row_normalise(counts: np.ndarray) -> np.ndarray:
    """Rows divided by their sums; a class with no samples keeps an all-zero row."""
    c = np.asarray(counts, dtype=np.float64)
    tot = c.sum(axis=1, keepdims=True)
    return np.divide(c, tot, out=np.zeros_like(c), where=tot > 0)


def per_class_topk(
    scores: np.ndarray, y: np.ndarray, classes: Sequence[str], k: int = 1
) -> dict[str, float | None]:
    """Top-k per class name; ``None`` for classes without samples."""
    out: dict[str, float | None] = {}
    for c, name in enumerate(classes):
        m = np.asarray(y) == c
        out[name] = topk_accuracy(np.asarray(scores)[m], np.asarray(y)[m], k) if m.any() else None
    return out


def unit_rows(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    return x / np.linalg.norm(x, axis=-1, keepdims=True).clip(1e-12)


def mean_unit(embs: np.ndarray, axis: int = 0) -> np.ndarray:
    """Tactus pooling: average unit embeddings along ``axis``, then renormalise."""
    return unit_rows(np.asarray(embs, dtype=np.float32).mean(axis=axis))


def pad_window(idx: np.ndarray, k: int) -> np.ndarray:
    """Frame indices (n,) with 1 <= n <= k -> (k,), repeating the last one (model.pad_frames)."""
    a = np.asarray(idx, dtype=np.int64).reshape(-1)
    if a.size == 0 or a.size > k:
        raise InvalidInputError(f"a window needs 1..{k} frames, got {a.size}")
    return np.concatenate([a, np.repeat(a[-1:], k - a.size)])


def ksweep_windows(tuples: np.ndarray, n: int) -> np.ndarray:
    """(T, K) tuple indices -> (T, K): the first ``n`` kept, the rest repeating the n-th."""
    t = np.asarray(tuples, dtype=np.int64)
    if not 1 <= n <= t.shape[1]:
        raise InvalidInputError(f"n must be in 1..{t.shape[1]}, got {n}")
    return np.concatenate([t[:, :n], np.repeat(t[:, n - 1 : n], t.shape[1] - n, axis=1)], axis=1)


def recording_windows(frames: np.ndarray, k: int, pool: int = RECORDING_POOL) -> np.ndarray:
    """A recording's valid frame indices (in order) -> (W, k) windows.

    More than ``pool`` frames: ``pool`` evenly spaced ones are kept. They are tiled in order
    into consecutive k-frame windows; the last, short one repeats its last frame.
    """
    fr = np.asarray(frames, dtype=np.int64).reshape(-1)
    if fr.size == 0:
        raise InvalidInputError("a recording needs at least one frame")
    if fr.size > pool:
        fr = fr[np.linspace(0, fr.size - 1, pool).round().astype(np.int64)]
    return np.stack([pad_window(fr[s : s + k], k) for s in range(0, fr.size, k)])


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def pair_spearman(confusion: np.ndarray, sim: np.ndarray) -> dict[str, Any]:
    """Spearman rho between confusion rates and similarities over ordered off-diagonal pairs.

    ``confusion``, ``sim``: (C, C). Returns rho, p and n_pairs (C * (C - 1)). A constant
    input (e.g. a perfect model: no off-diagonal confusion) gives rho = None.
    """
    c, s = np.asarray(confusion, np.float64), np.asarray(sim, np.float64)
    if c.shape != s.shape or c.ndim != 2 or c.shape[0] != c.shape[1]:
        raise InvalidInputError(f"need two (C, C) matrices, got {c.shape} and {s.shape}")
    off = ~np.eye(c.shape[0], dtype=bool)
    a, b = c[off], s[off]
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return {"rho": None, "p": None, "n_pairs": int(a.size)}
    # scipy.stats imported here, not at the top: it costs seconds at every pretrain, train and
    # eval start, and only this rank correlation uses it
    from scipy.stats import spearmanr

    res = spearmanr(a, b)
    return {
        "rho": _nan_to_none(res.statistic),
        "p": _nan_to_none(res.pvalue),
        "n_pairs": int(a.size),
    }


def text_confusion_correlation(
    confusion: np.ndarray, raw: np.ndarray, centred: np.ndarray
) -> dict[str, Any]:
    """The paper's "text space is not the error source" test: Spearman between the confusion
    rate of every ordered class pair and the cosine of the two class targets, uncentred and
    centred. ``raw``/``centred``: (C, D) target rows."""
    r, c = unit_rows(raw), unit_rows(centred)
    return {
        "uncentred": pair_spearman(confusion, r @ r.T),
        "centred": pair_spearman(confusion, c @ c.T),
    }


def top_confusions(
    confusion: np.ndarray, classes: Sequence[str], n: int = 10, min_rate: float = 0.0
) -> list[dict[str, Any]]:
    """The largest off-diagonal confusion rates, as (true, predicted, rate) rows."""
    c = np.asarray(confusion, np.float64).copy()
    np.fill_diagonal(c, -1.0)
    order = np.argsort(-c, axis=None, kind="stable")[:n]
    out = []
    for flat in order:
        i, j = divmod(int(flat), c.shape[1])
        if c[i, j] <= min_rate:
            break
        out.append({"true": classes[i], "pred": classes[j], "rate": float(c[i, j])})
    return out


def mean_std(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean and sample standard deviation (ddof=1; None for a single run) of the finite values."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0, "values": list(values)}
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if v.size > 1 else None,
        "n": int(v.size),
        "values": [None if x is None else float(x) for x in values],
    }


def aggregate_runs(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Table-1 style: mean and sample std per scalar metric (and per K-sweep point)."""
    keys = list(SCALAR_METRICS)
    agg = {k: mean_std([r.get(k) for r in runs]) for k in keys}
    for n in KSWEEP:
        vals = [r.get("ksweep", {}).get(str(n)) for r in runs]
        if any(v is not None for v in vals):
            agg[f"ksweep_{n}"] = mean_std(vals)
    return agg
