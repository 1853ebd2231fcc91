"""Where a hold starts and ends: the cutting rule of a touch stream's grasps (issue 46, item 6).

A *hold* is one object held, from contact onset to release. The touch sense stores no idle
window (no contact), so a release is a hole in a stream's stored windows; a re-grip of the
same object (the hand slips, loosens, takes hold again) is a short hole. :func:`hold_labels`
cuts one stream's stored windows, in time order, into holds: window *i* starts a new hold when

1. **release**: ``t[i] - max(t_end of the hold so far) > max_gap`` seconds
   (:data:`HOLD_MAX_GAP`); overlapping windows have gaps <= 0;
2. **change point**: ``cos(v[i], v[i-1]) < min_cos`` (:data:`HOLD_MIN_COS`): the embedding
   jumps between consecutive windows (another object taken with no release in between).

Only times and stored vectors decide, never labels, recordings or meta, and both rules look at
consecutive windows only, so a hold is found from its neighbourhood alone (the grasp search
reads a neighbourhood around its candidates, :mod:`tactus_memory.search.grasps`).

Measured, not assumed (``benchmarks/grasp_holds.py``, ``benchmarks/results/grasp_holds.json``:
the protocol's 26 held-out glove recordings with the demo checkpoint, each recording one known
hold; laid out as the protocol does, 10 s apart, and abutting, with no gap between them). Holes
in the stored windows come in steps at the glove's ~7.4 Hz: 0.14 s (one idle window dropped),
0.68 s (a re-grip: two dropped), 1.2 s and more. The cut before issue 46 (``max_gap`` 0.5 s)
split 3 of the 26 holds at a re-grip (completeness 0.88, 29 grasps); 0.75 s keeps all 26 whole
(26 grasps) and stays pure on the protocol's day. Abutting, where only a recording's own idle
frames part two objects, purity falls from 0.93 (0.5 s) to 0.87 (0.75 s), 0.82 (1.0 s) and
0.82 (2.0 s): a longer gap buys completeness with purity, so the gap stops at one re-grip.
``min_cos`` 0.2 (change point): consecutive windows of one recording have a median cosine of
0.87-0.96 with the shipped checkpoint (10th percentile 0.20-0.57 while the hand moves); with
the demo checkpoint it cut nothing on these days (the same figures with ``min_cos`` -1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.where import finite_float

#: a hole longer than this (seconds) between a stream's stored windows is a release: a new hold.
#: Above a re-grip's 0.68 s hole at the STAG glove's 7.4 Hz, below its 1.2 s (module docstring)
HOLD_MAX_GAP = 0.75
#: consecutive windows whose cosine is below this are in different holds (change point)
HOLD_MIN_COS = 0.2


@dataclass(frozen=True)
class HoldRule:
    """Where holds start and end (see the module docstring)."""

    max_gap: float = HOLD_MAX_GAP
    min_cos: float = HOLD_MIN_COS

    def __post_init__(self) -> None:
        if finite_float(self.max_gap, "max_gap") < 0:
            raise InvalidInputError(f"max_gap must be >= 0, got {self.max_gap!r}")
        if not -1.0 <= finite_float(self.min_cos, "min_cos") <= 1.0:
            raise InvalidInputError(f"min_cos must be in [-1, 1], got {self.min_cos!r}")


def hold_starts(
    t: np.ndarray, t_end: np.ndarray, vectors: np.ndarray, rule: HoldRule = HoldRule()
) -> np.ndarray:
    """(N,) bool: which of N windows of one stream, sorted by ``(t, id)``, start a hold.

    t, t_end: (N,) seconds; vectors: (N, D) unit rows. The first window always starts one."""
    n = len(t)
    starts = np.zeros(n, dtype=bool)
    if n == 0:
        return starts
    t = np.asarray(t, dtype=np.float64)
    ends = np.asarray(t_end, dtype=np.float64)
    v = np.asarray(vectors, dtype=np.float32)
    jump = np.r_[False, np.einsum("ij,ij->i", v[1:], v[:-1]) < rule.min_cos]
    starts[0] = True
    latest = ends[0]
    for i in range(1, n):  # the release rule needs the hold's running max end
        if jump[i] or t[i] - latest > rule.max_gap:
            starts[i] = True
            latest = ends[i]
        else:
            latest = max(latest, ends[i])
    return starts


def hold_labels(
    t: np.ndarray, t_end: np.ndarray, vectors: np.ndarray, rule: HoldRule = HoldRule()
) -> np.ndarray:
    """Hold labels 0, 1, ... for N windows of one stream sorted by ``(t, id)``: (N,) int64,
    non-decreasing (:func:`hold_starts` counted)."""
    starts = hold_starts(t, t_end, vectors, rule)
    return (np.cumsum(starts) - 1).astype(np.int64) if len(starts) else starts.astype(np.int64)


@dataclass(frozen=True)
class CutQuality:
    """A cut against known holds: ``purity`` the share of cut groups whose windows all come
    from one known hold; ``completeness`` the share of known holds whose windows all fall in
    one group; ``groups`` and ``singles`` (groups of one window); ``holds`` known."""

    purity: float
    completeness: float
    groups: int
    singles: int
    holds: int


def cut_quality(labels: np.ndarray, truth: np.ndarray) -> CutQuality:
    """Score a cut (labels (N,)) against the known hold of each window (truth (N,), any
    hashable values)."""
    labels = np.asarray(labels)
    truth = np.asarray(truth)
    if labels.shape != truth.shape or labels.ndim != 1 or len(labels) == 0:
        raise InvalidInputError("labels and truth must be equal-length non-empty (N,) arrays")
    groups, sizes = np.unique(labels, return_counts=True)
    holds = np.unique(truth)
    pure = sum(len(np.unique(truth[labels == g])) == 1 for g in groups)
    whole = sum(len(np.unique(labels[truth == h])) == 1 for h in holds)
    return CutQuality(
        purity=pure / len(groups),
        completeness=whole / len(holds),
        groups=len(groups),
        singles=int((sizes == 1).sum()),
        holds=len(holds),
    )
