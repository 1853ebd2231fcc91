"""Cluster tuples (STAG ObjectClusterDataset protocol) and their edge cases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import calibrate
from tactus_memory.training.data import load_stag
from tactus_memory.training.tuples import RESAMPLE_EVERY, TupleSampler, cluster_labels

K = 8


def blobs(n_groups: int, per_group: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 32, 32) calibrated frames in ``n_groups`` well separated groups, and the group ids."""
    rng = np.random.default_rng(seed)
    centres = rng.random((n_groups, 32, 32)).astype(np.float32)
    group = np.repeat(np.arange(n_groups), per_group)
    frames = centres[group] + rng.normal(0, 0.01, size=(group.size, 32, 32)).astype(np.float32)
    return np.clip(frames, 0, 1), group


def synthetic_pool(seed: int = 0):
    """Recordings of 60 (8 groups), 40 (8 groups), 3, 1 valid frames, plus invalid frames."""
    rng = np.random.default_rng(seed)
    parts, recs, valid = [], [], []
    for r, (n_valid, n_groups) in enumerate([(64, 8), (40, 8), (3, 3), (1, 1)]):
        frames, _ = blobs(n_groups, n_valid // n_groups, seed=seed + r)
        invalid = rng.random((5, 32, 32)).astype(np.float32)
        parts += [frames, invalid]
        recs += [r] * (len(frames) + 5)
        valid += [True] * len(frames) + [False] * 5
    order = rng.permutation(len(recs))  # interleave, so indices are not contiguous
    return (
        np.concatenate(parts)[order],
        np.array(recs)[order],
        np.array(valid)[order],
    )


# --------------------------------------------------------------------------- cluster_labels


def test_cluster_labels_recovers_separated_groups() -> None:
    frames, group = blobs(K, 12)
    labels = cluster_labels(frames, K, seed=0)
    assert labels.shape == (96,) and labels.dtype == np.int64
    # a bijection between true groups and clusters
    pairs = set(zip(group.tolist(), labels.tolist(), strict=True))
    assert len(pairs) == K and len({p[1] for p in pairs}) == K
    np.testing.assert_array_equal(labels, cluster_labels(frames, K, seed=0))


def test_cluster_labels_small_and_degenerate_inputs() -> None:
    frames, _ = blobs(3, 1)
    np.testing.assert_array_equal(cluster_labels(frames, K, 0), [0, 1, 2])  # n < k
    np.testing.assert_array_equal(cluster_labels(frames[:1], K, 0), [0])  # n == 1
    assert cluster_labels(frames[:0], K, 0).shape == (0,)
    same = np.repeat(frames[:2], 10, axis=0)  # 20 frames, only 2 distinct: empty clusters
    labels = cluster_labels(same, K, 0)
    assert sorted(np.unique(labels).tolist()) == [0, 1]  # dense ids, no empty cluster ids
    assert len(set(zip(labels.tolist(), [0] * 10 + [1] * 10, strict=True))) == 2
    flat = np.repeat(frames[:1], 12, axis=0)  # 12 identical frames: one cluster
    np.testing.assert_array_equal(cluster_labels(flat, K, 0), np.zeros(12))
    with pytest.raises(InvalidInputError):
        cluster_labels(frames, 0, 0)


# --------------------------------------------------------------------------- TupleSampler


def check_invariants(t: np.ndarray, sampler: TupleSampler, rec: np.ndarray, valid: np.ndarray):
    assert t.dtype == np.int64 and t.shape == (len(sampler.anchors), K)
    np.testing.assert_array_equal(t[:, 0], sampler.anchors)
    assert (rec[t] == rec[t[:, :1]]).all(), "a member from another recording"
    assert valid[t].all(), "an invalid member"


@pytest.mark.parametrize("mode", ["cluster", "random"])
def test_tuple_members_share_recording_and_are_valid(mode: str) -> None:
    frames, rec, valid = synthetic_pool()
    s = TupleSampler(frames, rec, valid, k=K, mode=mode, seed=0)
    assert len(s) == valid.sum()  # every valid frame anchors a tuple, small recordings too
    for seed in range(3):
        check_invariants(s.sample(np.random.default_rng(seed)), s, rec, valid)


def test_cluster_tuples_draw_one_frame_per_cluster() -> None:
    frames, rec, valid = synthetic_pool()
    s = TupleSampler(frames, rec, valid, k=K, mode="cluster", seed=0)
    t = s.fixed(1)
    for r in (0, 1):  # the recordings with >= k valid frames
        clusters = s.clusters(r)
        assert len(clusters) == K
        label = {int(i): c for c, members in enumerate(clusters) for i in members}
        rows = t[rec[t[:, 0]] == r]
        assert len(rows) == (64 if r == 0 else 40)
        for row in rows:
            assert sorted(label[int(i)] for i in row) == list(range(K))
    # companions are shuffled: the cluster order of column 1 varies across rows
    label0 = {int(i): c for c, members in enumerate(s.clusters(0)) for i in members}
    first = [label0[int(i)] for i in t[rec[t[:, 0]] == 0][:, 1]]
    assert len(set(first)) > 2


def test_small_recordings_fill_tuples() -> None:
    frames, rec, valid = synthetic_pool()
    s = TupleSampler(frames, rec, valid, k=K, mode="cluster", seed=0)
    t = s.fixed(0)
    single = t[rec[t[:, 0]] == 3]
    assert single.shape == (1, K) and (single == single[0, 0]).all()  # anchor repeated
    three = t[rec[t[:, 0]] == 2]
    members = set(np.flatnonzero((rec == 2) & valid).tolist())
    assert three.shape == (3, K)
    for row in three:
        assert set(row.tolist()) == members  # every frame of the recording appears


def test_random_mode_has_no_duplicate_companions() -> None:
    frames, rec, valid = synthetic_pool()
    s = TupleSampler(frames, rec, valid, k=K, mode="random", seed=0)
    t = s.sample(np.random.default_rng(3))
    big = np.isin(rec[t[:, 0]], [0, 1])
    for row in t[big]:
        assert len(set(row.tolist())) == K  # no repeats, anchor not among companions
    # and companions are actually random: two draws differ
    assert not np.array_equal(t, s.sample(np.random.default_rng(4)))


def test_fixed_is_deterministic() -> None:
    frames, rec, valid = synthetic_pool()
    a = TupleSampler(frames, rec, valid, k=K, seed=0)
    b = TupleSampler(frames, rec, valid, k=K, seed=0)
    np.testing.assert_array_equal(a.fixed(7), a.fixed(7))
    np.testing.assert_array_equal(a.fixed(7), b.fixed(7))  # a fresh sampler: same tiling
    assert not np.array_equal(a.fixed(7), a.fixed(8))


def test_anchors_mask_restricts_and_stays_valid() -> None:
    frames, rec, valid = synthetic_pool()
    balanced = np.random.default_rng(0).random(len(rec)) < 0.5
    s = TupleSampler(frames, rec, valid, anchors=balanced, k=K, seed=0)
    np.testing.assert_array_equal(s.anchors, np.flatnonzero(valid & balanced))
    t = s.fixed(0)
    check_invariants(t, s, rec, valid)
    # companions still come from all valid frames, not only balanced ones
    assert (~balanced[t[:, 1:]]).any()
    idx = TupleSampler(frames, rec, valid, anchors=np.flatnonzero(balanced), k=K, seed=0)
    np.testing.assert_array_equal(idx.anchors, s.anchors)


def test_bad_arguments() -> None:
    frames, rec, valid = synthetic_pool()
    with pytest.raises(InvalidInputError, match="mode"):
        TupleSampler(frames, rec, valid, mode="contiguous")
    with pytest.raises(InvalidInputError):
        TupleSampler(frames[:-1], rec, valid)
    with pytest.raises(InvalidInputError):
        TupleSampler(frames, rec, valid[:-1])
    with pytest.raises(InvalidInputError, match="calibrated"):
        TupleSampler(frames * 600, rec, valid)  # raw readings, not calibrated


def test_resample_period() -> None:
    assert RESAMPLE_EVERY == 500


@pytest.mark.slow
def test_real_weights_tuples(stag_dir: Path) -> None:
    d = load_stag(stag_dir / "weights_lite")
    s = TupleSampler(calibrate(d.pressure), d.recording_id, d.valid, d.anchor_mask(), k=K)
    t = s.fixed(0)
    np.testing.assert_array_equal(t, TupleSampler.from_stag(d, k=K).fixed(0))
    assert t.shape == (2301, K)
    check_invariants(t, s, d.recording_id, d.valid)
    assert all(len(s.clusters(r)) == K for r in s.recordings)


def test_from_stag_applies_split_valid_and_balanced(tmp_path: Path) -> None:
    from tests.helpers.stag_synth import make_fields, write_v73

    fields = make_fields("classification", [30, 25, 12, 3], seed=6)
    d = load_stag(write_v73(tmp_path / "m.mat", fields))
    for split in ("train", "test"):
        s = TupleSampler.from_stag(d, split, k=K)
        t = s.fixed(0)
        np.testing.assert_array_equal(s.anchors, np.flatnonzero(d.anchor_mask(split)))
        assert d.valid_mask(split)[t].all() and d.balanced[t[:, 0]].all()
        assert (d.recording_id[t] == d.recording_id[t[:, :1]]).all()
