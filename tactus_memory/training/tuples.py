"""Cluster-sampled grasp tuples (a port of the STAG ``ObjectClusterDataset`` protocol).

Spec: ``../shared/stag-format.md`` "Reference sampling"; paper Sec. Method "Data path".
Each recording's valid frames are clustered once (PCA to 8, one global min-max rescale,
k-means with k = tuple length); a tuple is an anchor plus one random frame from each other
cluster of its recording, companions shuffled. ``mode="random"`` draws the k-1 companions
without replacement from the recording's valid frames.

Edge cases the reference code does not handle (documented behaviour here):

- a recording with fewer than k valid frames: every frame is its own cluster; the tuple
  takes each other frame once and fills the remaining slots by drawing the recording's
  valid frames with replacement (the anchor included), so every anchor yields a tuple;
  a single-frame recording gives the anchor repeated k times;
- fewer than k non-empty clusters (duplicate frames): same fill rule;
- random mode with fewer than k-1 other valid frames: all of them, then the same fill.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np
from sklearn.cluster import KMeans
from sklearn.decomposition import PCA
from threadpoolctl import threadpool_limits

from tactus_memory.errors import InvalidInputError

if TYPE_CHECKING:
    from tactus_memory.touch.profile import SensorProfile
    from tactus_memory.training.data import StagData

PCA_COMPONENTS = 8  # STAG ObjectClusterDataset: PCA to 8 components before k-means
KMEANS_N_INIT = 50  # STAG ObjectClusterDataset: KMeans(k-means++, n_init=50)
DEFAULT_K = 8  # tuple length K = 8 (paper Sec. Method)
RESAMPLE_EVERY = 500  # train tuples are redrawn every 500 steps (paper Sec. Method)
MODES = ("cluster", "random")
_CHUNK = 1 << 21  # random mode: at most this many random keys drawn at once


def cluster_labels(frames: np.ndarray, k: int, seed: int) -> np.ndarray:
    """``frames``: (n, 32, 32) calibrated -> (n,) int64 cluster ids in ``0..m-1``, m <= k.

    Flatten to 1024, PCA to min(8, n) components, ONE global min-max rescale (not per
    dimension), KMeans(k, k-means++, n_init=50, random_state=seed). With n <= k each frame
    is its own cluster; empty clusters are dropped and the ids renumbered densely.
    """
    x = np.asarray(frames)
    if x.ndim < 1:
        raise InvalidInputError(f"frames must be (n, ...), got shape {x.shape}")
    if k < 1:
        raise InvalidInputError(f"k must be >= 1, got {k}")
    n = x.shape[0]
    if n <= k:
        return np.arange(n, dtype=np.int64)
    flat = x.reshape(n, -1).astype(np.float64)
    if not np.all(np.isfinite(flat)):
        raise InvalidInputError("frames contain NaN or inf")
    n_comp = min(PCA_COMPONENTS, n, flat.shape[1])
    # one BLAS/OpenMP thread: these problems are tiny and thread start-up dominated (measured
    # 0.4 s -> 0.02 s per 85-frame recording on a shared 2-core machine)
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ConvergenceWarning when distinct points < k
        z = PCA(n_components=n_comp, svd_solver="full").fit_transform(flat)
        lo, hi = z.min(), z.max()
        z = (z - lo) / (hi - lo) if hi > lo else np.zeros_like(z)
        labels = KMeans(
            n_clusters=k, init="k-means++", n_init=KMEANS_N_INIT, random_state=seed
        ).fit_predict(z)
    _, dense = np.unique(labels, return_inverse=True)
    return dense.astype(np.int64).reshape(-1)


def _as_index(mask_or_idx: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(mask_or_idx)
    if a.dtype == bool:
        if a.shape != (n,):
            raise InvalidInputError(f"{name} mask must have shape ({n},), got {a.shape}")
        return np.flatnonzero(a).astype(np.int64)
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise InvalidInputError(f"{name} must be a bool mask or integer indices")
    idx = a.astype(np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InvalidInputError(f"{name} indices out of range 0..{n - 1}")
    return np.unique(idx)


class TupleSampler:
    """Tuples of k frame indices, column 0 the anchor.

    ``calibrated``: (N, 32, 32) float calibrated frames; ``recording_id``: (N,) ints;
    ``valid``: (N,) bool (or indices) of frames allowed in tuples; ``anchors``: bool mask or
    indices, default ``valid``; anchors outside ``valid`` are dropped. Clusters are computed
    once per recording over its valid frames (seeded from ``seed`` and the recording id).
    """

    def __init__(
        self,
        calibrated: np.ndarray,
        recording_id: np.ndarray,
        valid: np.ndarray,
        anchors: np.ndarray | None = None,
        k: int = DEFAULT_K,
        mode: str = "cluster",
        seed: int = 0,
    ) -> None:
        frames = np.asarray(calibrated)
        rec = np.asarray(recording_id).reshape(-1).astype(np.int64)
        n = rec.shape[0]
        if frames.shape[0] != n:
            raise InvalidInputError(
                f"calibrated has {frames.shape[0]} frames but recording_id has {n}"
            )
        if frames.size and (float(frames.min()) < 0.0 or float(frames.max()) > 1.0):
            raise InvalidInputError(
                "TupleSampler expects calibrated frames in [0, 1] (tactus_memory.touch.profile."
                f"calibrate), got values {frames.min()}..{frames.max()}"
            )
        if mode not in MODES:
            raise InvalidInputError(f"mode must be one of {MODES}, got {mode!r}")
        if k < 1:
            raise InvalidInputError(f"k must be >= 1, got {k}")
        self.k, self.mode, self.seed = int(k), mode, int(seed)
        valid_idx = _as_index(valid, n, "valid")
        anchor_idx = valid_idx if anchors is None else _as_index(anchors, n, "anchors")
        anchor_idx = np.intersect1d(anchor_idx, valid_idx)

        # per recording: its valid frames, and (cluster mode) those frames grouped by cluster
        self._members: dict[int, np.ndarray] = {}
        self._clusters: dict[int, list[np.ndarray]] = {}
        self._label: dict[int, np.ndarray] = {}  # cluster id per member, aligned to _members
        for r in np.unique(rec[valid_idx]):
            members = valid_idx[rec[valid_idx] == r]
            self._members[int(r)] = members
            if mode == "cluster":
                rseed = int(np.random.SeedSequence([self.seed, int(r)]).generate_state(1)[0])
                labels = cluster_labels(frames[members], self.k, rseed)
                self._label[int(r)] = labels
                self._clusters[int(r)] = [members[labels == c] for c in range(labels.max() + 1)]
        self.anchors: np.ndarray = anchor_idx  # (T,) int64 frame indices
        self._anchor_rec = rec[anchor_idx]

    @classmethod
    def from_stag(
        cls,
        data: StagData,
        split: str | None = None,
        *,
        k: int = DEFAULT_K,
        mode: str = "cluster",
        seed: int = 0,
        profile: SensorProfile | None = None,
    ) -> TupleSampler:
        """The reference protocol on a loaded subset: members from ``data.valid_mask(split)``,
        anchors ``data.anchor_mask(split)`` (valid, in the split, isBalanced)."""
        from tactus_memory.touch.profile import STAG_GLOVE

        return cls(
            data.calibrated(profile or STAG_GLOVE),
            data.recording_id,
            data.valid_mask(split),
            data.anchor_mask(split),
            k=k,
            mode=mode,
            seed=seed,
        )

    def __len__(self) -> int:
        return int(self.anchors.size)

    @property
    def recordings(self) -> np.ndarray:
        """Recording ids that have valid frames."""
        return np.array(sorted(self._members), dtype=np.int64)

    def clusters(self, recording: int) -> list[np.ndarray]:
        """Frame indices of each cluster of ``recording`` (cluster mode)."""
        return list(self._clusters[int(recording)])

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """(T, k) int64 frame indices, one row per anchor in ``anchors`` order."""
        out = np.empty((self.anchors.size, self.k), dtype=np.int64)
        out[:, 0] = self.anchors
        if self.k == 1 or self.anchors.size == 0:
            return out
        for r in np.unique(self._anchor_rec):
            rows = np.flatnonzero(self._anchor_rec == r)
            comp = (
                self._cluster_companions(int(r), rows, rng)
                if self.mode == "cluster"
                else self._random_companions(int(r), rows, rng)
            )
            out[rows, 1:] = rng.permuted(comp, axis=1)
        return out

    def fixed(self, seed: int) -> np.ndarray:
        """A fixed tiling (test tuples): identical output for an identical seed."""
        return self.sample(np.random.default_rng(seed))

    # ---- companions: (len(rows), k-1) frame indices for the anchors at ``rows``
    def _fill(self, members: np.ndarray, t: int, n_fill: int, rng: np.random.Generator):
        return members[rng.integers(0, members.size, size=(t, n_fill))]

    def _cluster_companions(self, r: int, rows: np.ndarray, rng: np.random.Generator):
        members, labels, clusters = self._members[r], self._label[r], self._clusters[r]
        anchors = self.anchors[rows]
        own = labels[np.searchsorted(members, anchors)]  # anchor's cluster
        t, m = rows.size, len(clusters)
        draws = np.empty((t, m), dtype=np.int64)
        for c, frames in enumerate(clusters):
            draws[:, c] = frames[rng.integers(0, frames.size, size=t)]
        keep = np.arange(m)[None, :] != own[:, None]  # drop the anchor's own cluster
        others = draws[keep].reshape(t, m - 1)
        if m - 1 >= self.k - 1:
            return others[:, : self.k - 1]
        return np.concatenate([others, self._fill(members, t, self.k - m, rng)], axis=1)

    def _random_companions(self, r: int, rows: np.ndarray, rng: np.random.Generator):
        members = self._members[r]
        anchors = self.anchors[rows]
        t, n, need = rows.size, members.size, self.k - 1
        pos = np.searchsorted(members, anchors)
        n_take = min(need, n - 1)
        comp = np.empty((t, n_take), dtype=np.int64)
        step = max(1, _CHUNK // max(n, 1))
        for s in range(0, t, step):
            e = min(t, s + step)
            keys = rng.random((e - s, n))
            keys[np.arange(e - s), pos[s:e]] = np.inf  # never the anchor itself
            if n_take:
                pick = np.argpartition(keys, n_take - 1, axis=1)[:, :n_take]
                comp[s:e] = members[pick]
        if n_take == need:
            return comp
        return np.concatenate([comp, self._fill(members, t, need - n_take, rng)], axis=1)


def consecutive_windows(
    anchors: np.ndarray, recording_id: np.ndarray, k: int, rng: np.random.Generator
) -> np.ndarray:
    """(T,) anchor frame indices -> (T, k) runs of k consecutive frames that hold the anchor.

    The stream's kind of window (``touch/windows.py``: consecutive frames of one recording),
    drawn for training. Frames must be stored recording by recording in time order (as
    ``StagData`` keeps them); the run is placed at a random offset around its anchor and
    clipped to the anchor's recording; a recording shorter than k repeats its last frame.
    """
    rec = np.asarray(recording_id, dtype=np.int64).reshape(-1)
    a = np.asarray(anchors, dtype=np.int64).reshape(-1)
    # first/last frame index of each anchor's recording (recordings are contiguous runs)
    starts = np.searchsorted(rec, rec[a], side="left")
    ends = np.searchsorted(rec, rec[a], side="right") - 1
    if np.any(rec[starts] != rec[a]) or np.any(np.diff(rec) < 0):
        raise InvalidInputError("consecutive windows need frames sorted by recording")
    s = a - rng.integers(0, k, size=a.size)
    s = np.clip(s, starts, np.maximum(starts, ends - k + 1))
    out = s[:, None] + np.arange(k)[None, :]
    return np.minimum(out, ends[:, None])
