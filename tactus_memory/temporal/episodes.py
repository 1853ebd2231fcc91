"""Episodes: change-point segmentation of one stream's embeddings (pure numpy).

A *stream* is the items of one ``(session, sense, source)``: one glove, one camera, one note
taker. Streams are segmented independently, because a cosine between a touch vector and a
note is dominated by the modality gap, not by a change of content.

Change-point rule (deterministic, items in time order ``(t, id)``): item *i* opens a new
episode when any of

1. **time gap**: ``t[i] - max(t_end[:i] of the episode) > max_gap`` (seconds): two grasps of
   the same mug a minute apart are two episodes;
2. **jump**: ``cos(v[i], v[i-1]) < min_cos``: an abrupt change between consecutive items;
3. **drift**: ``cos(v[i], mean of the episode so far) < mean_cos``: a slow change that never
   trips (2) but has moved away from what the episode was about.

The defaults are overridable per call. Measured with the shipped touch checkpoint on the STAG
``weights`` subset: consecutive 8-frame windows of one recording have a median cosine of
0.87-0.96 (the 10th percentile, 0.20-0.57, is where the hand moves), windows of valid grasps
of different objects a median of -0.41-0.15 (90th percentile at most 0.49). MiniLM notes on
one topic ("picked up the mug" / "put the mug down") have cosines 0.61-0.70, unrelated notes
0.07-0.49: a run of notes on one topic splits unless ``min_cos`` is lowered to about 0.55.
The episode's representative is the member closest (cosine) to the episode's mean vector.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactus_memory.vectors import vector_column

#: a new episode when consecutive items' cosine drops below this (an abrupt change)
EPISODE_MIN_COS = 0.7
#: a new episode when an item's cosine to its episode's running mean drops below this (drift)
EPISODE_MEAN_COS = 0.6
#: a new episode when the time gap to the episode's latest end exceeds this (seconds)
EPISODE_MAX_GAP = 5.0
#: an episode rule: (min_cos, mean_cos, max_gap)
EpisodeRule = tuple[float, float, float]


def check_rule(min_cos: float, mean_cos: float, max_gap: float) -> None:
    """Raise ValueError-compatible InvalidInputError on thresholds outside their range."""
    from tactus_memory.errors import InvalidInputError
    from tactus_memory.where import finite_float

    for name, value in (("min_cos", min_cos), ("mean_cos", mean_cos)):
        if not -1.0 <= finite_float(value, name) <= 1.0:
            raise InvalidInputError(f"{name} must be in [-1, 1], got {value!r}")
    if finite_float(max_gap, "max_gap") < 0:
        raise InvalidInputError(f"max_gap must be >= 0, got {max_gap!r}")


def segment(
    t: np.ndarray,
    t_end: np.ndarray,
    vectors: np.ndarray,
    *,
    min_cos: float = EPISODE_MIN_COS,
    mean_cos: float = EPISODE_MEAN_COS,
    max_gap: float = EPISODE_MAX_GAP,
) -> np.ndarray:
    """Episode labels 0, 1, ... for N items of one stream, already sorted by time.

    t, t_end: (N,) seconds; vectors: (N, D) unit rows. Returns (N,) int64, non-decreasing.
    """
    n = len(t)
    labels = np.zeros(n, dtype=np.int64)
    if n == 0:
        return labels
    v = np.asarray(vectors, dtype=np.float64)
    label = 0
    total = v[0].copy()
    latest_end = float(t_end[0])
    for i in range(1, n):
        mean = total / max(np.linalg.norm(total), 1e-12)
        gap = float(t[i]) - latest_end
        jump = float(v[i] @ v[i - 1])
        drift = float(v[i] @ mean)
        if gap > max_gap or jump < min_cos or drift < mean_cos:
            label += 1
            total = v[i].copy()
            latest_end = float(t_end[i])
        else:
            total += v[i]
            latest_end = max(latest_end, float(t_end[i]))
        labels[i] = label
    return labels


def representative(vectors: np.ndarray) -> int:
    """Index of the row closest (cosine) to the normalised mean of unit rows (first on ties)."""
    v = np.asarray(vectors, dtype=np.float64)
    mean = v.sum(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-12)
    return int(np.argmax(v @ mean))


def streams(tbl: Any) -> dict[tuple[str, str], np.ndarray]:
    """(sense, source) -> row indices of the Arrow table ``tbl`` sorted by (t, id)."""
    senses = tbl.column("sense").to_pylist()
    sources = [s or "" for s in tbl.column("source").to_pylist()]
    ids = tbl.column("id").to_pylist()
    t = tbl.column("t").to_pylist()
    by: dict[tuple[str, str], list[int]] = {}
    for i, key in enumerate(zip(senses, sources, strict=True)):
        by.setdefault(key, []).append(i)
    return {
        key: np.array(sorted(idx, key=lambda i: (t[i], ids[i])), dtype=np.int64)
        for key, idx in by.items()
    }


def number_episodes(tbl: Any, dim: int, rule: EpisodeRule) -> tuple[list[str], np.ndarray]:
    """The rows of one session (Arrow table: id, sense, source, t, t_end, (D,) vector)
    segmented stream by stream under ``rule`` (min_cos, mean_cos, max_gap): (ids, (N,) int64
    episode numbers), numbered 0, 1, ... by (first item's time, sense, source)."""
    min_cos, mean_cos, max_gap = rule
    ids = tbl.column("id").to_pylist()
    if not ids:
        return [], np.zeros(0, dtype=np.int64)
    firsts: list[tuple[float, str, str, int, np.ndarray]] = []
    vecs = vector_column(tbl, dim)
    t = tbl.column("t").to_numpy()
    t_end = tbl.column("t_end").to_numpy()
    for (sense, source), idx in sorted(streams(tbl).items()):
        labels = segment(
            t[idx], t_end[idx], vecs[idx], min_cos=min_cos, mean_cos=mean_cos, max_gap=max_gap
        )
        for lab in np.unique(labels):
            members = idx[labels == lab]
            firsts.append((float(t[members[0]]), sense, source, int(lab), members))
    firsts.sort(key=lambda f: (f[0], f[1], f[2], f[3]))
    episode = np.zeros(len(ids), dtype=np.int64)
    for number, (*_, members) in enumerate(firsts):
        episode[members] = number
    return ids, episode
