"""Where holds start and end (issue 46, item 6): one hold, one grasp, on synthetic glove frames
cut by the library's own stream windowing (no model, no store)."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.recordings.samples import synthetic_grasp
from tactus_memory.search.grasps import GraspRule, grasp_labels
from tactus_memory.search.holds import (
    HOLD_MAX_GAP,
    HoldRule,
    cut_quality,
    hold_labels,
    hold_starts,
)
from tactus_memory.touch.windows import cut_windows

HZ = 7.4  # the STAG glove's frame rate
K, STRIDE = 8, 4  # the stream windowing's window and stride
#: frames of no contact: a re-grip (the hand loosens on the same object: the stored windows
#: have a 0.68 s hole at 7.4 Hz) and a release between two objects (a 1.2 s hole or more)
REGRIP, RELEASE = 12, 24


def _day(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mug, re-grip, mug, release, pen, then a cup taken straight from the pen (no release).
    Returns the stored (non-idle) windows' t, t_end (N,), unit vectors (N, 4) and their known
    hold (N,): the last object its frames touch."""
    rng = np.random.default_rng(seed)

    def rest(n: int) -> np.ndarray:
        return (512 + rng.normal(0, 2, (n, 32, 32))).astype(np.int16)

    parts = [(rest(8), -1), (synthetic_grasp(40), 0), (rest(REGRIP), -1), (synthetic_grasp(40), 0)]
    parts += [(rest(RELEASE), -1), (synthetic_grasp(40, 1), 1), (synthetic_grasp(40, 2), 2)]
    frames = np.concatenate([p for p, _ in parts])
    obj = np.concatenate([np.full(len(p), o) for p, o in parts])
    w = cut_windows(frames, np.arange(len(frames)) / HZ, window=K, stride=STRIDE)
    keep = ~w.idle
    hold = obj[w.start[keep, None] + np.arange(K)].max(axis=1)  # the object it touches last
    v = np.eye(4, dtype=np.float32)[hold] + rng.normal(0, 0.05, (int(keep.sum()), 4))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return w.t[keep], w.t_end[keep], v.astype(np.float32), hold


def test_one_hold_is_one_grasp_on_synthetic_frames() -> None:
    t, t_end, v, hold = _day()
    assert set(hold.tolist()) == {0, 1, 2}  # the idle windows were dropped by the windowing
    holes = t[1:] - np.maximum.accumulate(t_end)[:-1]
    release, regrip = np.sort(holes)[-1], np.sort(holes)[-2]
    assert release > HOLD_MAX_GAP and 0.5 < regrip < HOLD_MAX_GAP  # 0.68 s: one re-grip hole
    labels = hold_labels(t, t_end, v)
    q = cut_quality(labels, hold)
    assert (q.purity, q.completeness, q.groups, q.holds) == (1.0, 1.0, 3, 3)
    # the search's grasp cut is the same rule
    assert grasp_labels(t, t_end, v).tolist() == labels.tolist()
    # the cut before issue 46 (0.5 s) made the re-grip two answers
    old = cut_quality(hold_labels(t, t_end, v, HoldRule(max_gap=0.5)), hold)
    assert (old.purity, old.groups) == (1.0, 4) and old.completeness == pytest.approx(2 / 3)
    assert grasp_labels(t, t_end, v, GraspRule(max_gap=0.5)).max() == 3
    # the pen -> cup change has no release: only the change point cuts it
    loose = cut_quality(hold_labels(t, t_end, v, HoldRule(min_cos=-1.0)), hold)
    assert loose.groups == 2 and loose.purity == 0.5
    starts = hold_starts(t, t_end, v)
    assert starts[0] and starts.sum() == 3 and np.array_equal(np.cumsum(starts) - 1, labels)


def test_hold_rule_and_quality_refuse_bad_input() -> None:
    assert hold_labels(np.zeros(0), np.zeros(0), np.zeros((0, 4))).shape == (0,)
    with pytest.raises(InvalidInputError):
        HoldRule(max_gap=-1.0)
    with pytest.raises(InvalidInputError):
        HoldRule(min_cos=2.0)
    with pytest.raises(InvalidInputError):
        cut_quality(np.zeros(3), np.zeros(2))
