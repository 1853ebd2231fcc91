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

import numpy as np
from pydantic import BaseModel

#: a new episode when consecutive items' cosine drops below this (an abrupt change)
EPISODE_MIN_COS = 0.7
#: a new episode when an item's cosine to its episode's running mean drops below this (drift)
EPISODE_MEAN_COS = 0.6
#: a new episode when the time gap to the episode's latest end exceeds this (seconds)
EPISODE_MAX_GAP = 5.0


class Episode(BaseModel):
    """One coherent stretch of one stream: ``t``/``t_end`` as stored, ``t_aligned`` /
    ``t_end_aligned`` on the session clock (plus the stream's clock offset)."""

    session: str
    sense: str
    source: str = ""
    episode: int
    t: float
    t_end: float
    t_aligned: float
    t_end_aligned: float
    n: int
    representative: str


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
