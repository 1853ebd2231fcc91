"""Trajectories and places: the checks on a batch of poses, and where an item happened.

A session's poses (``t: (N,)`` on the session clock, ``position: (N, 3)``, optional
``orientation: (N, 4)`` unit quaternions (x, y, z, w), one ``frame``) are stored in their own
table. An item without an explicit position is placed on the session trajectory at the
middle of its time span: position linearly interpolated between the two poses around it,
orientation by slerp (:class:`scipy.spatial.transform.Rotation`). It stays unplaced when no
pose lies within :data:`POSE_TOLERANCE` seconds of that middle time (the span is outside the
trajectory, or in a gap of it), so a robot that stood still off the record is not placed by
guesswork. When a session has poses in several frames, an item is placed in the first frame
of :func:`frame_order` that places it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_COORDINATE, MAX_SECONDS
from tactus_memory.times import check_time
from tactus_memory.where import DEFAULT_FRAME, check_position

#: an item is placed only when a pose lies within this many seconds of the middle of its
#: span (odometry runs at 10-100 Hz, so a live trajectory always has one; a gap longer than
#: twice this leaves the items inside it unplaced)
POSE_TOLERANCE = 1.0
#: a quaternion's norm may differ from 1 by this much (float32 round trips, ROS messages)
UNIT_TOLERANCE = 1e-3
#: the most poses one ``add_poses`` call writes (about 3 h of odometry at 100 Hz)
MAX_POSES = 1_000_000


def _array(value: Any, what: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what} must be numbers") from None


def check_poses(
    t: Any, position: Any, orientation: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``t: (N,)`` strictly increasing finite times, ``position: (N, 3)`` finite,
    ``orientation: (N, 4)`` finite unit quaternions (x, y, z, w) or None -> float64 arrays.
    Raises :class:`~tactus_memory.errors.InvalidInputError` naming the first problem."""
    ts = _array(t, "t")
    pos = _array(position, "position")
    if ts.ndim != 1 or ts.shape[0] == 0:
        raise InvalidInputError(f"t must be a non-empty (N,) array, got shape {ts.shape}")
    n = ts.shape[0]
    if n > MAX_POSES:
        raise InvalidInputError(f"{n} poses in one call; limit {MAX_POSES}")
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise InvalidInputError(f"position must be (N, 3), got shape {pos.shape}")
    if pos.shape[0] != n:
        raise InvalidInputError(f"position has {pos.shape[0]} rows for {n} times")
    _finite(ts, "t")
    far_t = np.flatnonzero(np.abs(ts) > MAX_SECONDS)
    if far_t.size:  # the one time rule (tactus_memory/times.py), its message
        check_time(float(ts[far_t[0]]), f"t[{int(far_t[0])}]")
    _finite(pos, "position")
    far = np.flatnonzero((np.abs(pos) > MAX_COORDINATE).any(axis=1))
    if far.size:
        raise InvalidInputError(
            f"position {int(far[0])} is beyond +-{MAX_COORDINATE:g} m: {pos[far[0]].tolist()}"
        )
    steps = np.diff(ts)
    if (steps <= 0).any():
        i = int(np.flatnonzero(steps <= 0)[0]) + 1
        kind = "duplicate" if steps[i - 1] == 0 else "unsorted"
        raise InvalidInputError(
            f"t must be strictly increasing: {kind} time {float(ts[i])!r} at index {i} "
            f"(after {float(ts[i - 1])!r})"
        )
    if orientation is None:
        return ts, pos, None
    ori = _array(orientation, "orientation")
    if ori.ndim != 2 or ori.shape[1] != 4:
        raise InvalidInputError(f"orientation must be (N, 4) quaternions, got shape {ori.shape}")
    if ori.shape[0] != n:
        raise InvalidInputError(f"orientation has {ori.shape[0]} rows for {n} times")
    _finite(ori, "orientation")
    norms = np.linalg.norm(ori, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise InvalidInputError(
            f"orientation {i} is not a unit quaternion (norm {norms[i]:.6g}); "
            "send (x, y, z, w) with norm 1"
        )
    return ts, pos, ori / norms[:, None]


def _finite(a: np.ndarray, what: str) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        i = int(np.flatnonzero(bad.reshape(a.shape[0], -1).any(axis=1))[0])
        raise InvalidInputError(f"{what} has a NaN or infinite value at index {i}")


@dataclass
class Trajectory:
    """One frame's poses of a session, sorted by time: ``t: (N,)``, ``position: (N, 3)``,
    ``orientation: (N, 4)`` with NaN rows where a pose had none."""

    frame: str
    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray

    @classmethod
    def from_rows(cls, frame: str, t: Any, position: Any, orientation: Any) -> Trajectory:
        """Poses of several calls and sources merged: sorted by time, one pose per time
        (the first stored)."""
        ts = np.asarray(t, dtype=np.float64)
        order = np.argsort(ts, kind="stable")
        ts = ts[order]
        keep = np.concatenate([[True], np.diff(ts) > 0]) if ts.size else np.zeros(0, bool)
        idx = order[keep]
        return cls(
            frame, ts[keep], np.asarray(position, np.float64)[idx],
            np.asarray(orientation, np.float64)[idx],
        )  # fmt: skip

    def place(self, when: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``when: (M,)`` times -> (placed ``(M,)`` bool, position ``(M, 3)``, orientation
        ``(M, 4)``; NaN where unplaced or the poses around carry no orientation)."""
        from scipy.spatial.transform import Rotation

        m = np.asarray(when, dtype=np.float64)
        n = self.t.size
        hi = np.clip(np.searchsorted(self.t, m, side="right"), 1, max(n - 1, 1))
        lo = hi - 1 if n > 1 else np.zeros_like(hi)
        hi = np.minimum(hi, n - 1)
        t_lo, t_hi = self.t[lo], self.t[hi]
        nearest = np.minimum(np.abs(m - t_lo), np.abs(m - t_hi))
        placed = nearest <= POSE_TOLERANCE
        span = t_hi - t_lo
        with np.errstate(over="ignore"):  # a subnormal span (poses at 0 and 5e-324): clipped
            alpha = np.divide(m - t_lo, span, out=np.zeros_like(m), where=span > 0)
        alpha = np.clip(alpha, 0, 1)
        pos = self.position[lo] + alpha[:, None] * (self.position[hi] - self.position[lo])
        ori = np.full((m.size, 4), np.nan)
        q_lo, q_hi = self.orientation[lo], self.orientation[hi]
        has = placed & np.isfinite(q_lo).all(axis=1) & np.isfinite(q_hi).all(axis=1)
        if has.any():
            r_lo = Rotation.from_quat(q_lo[has])
            delta = (r_lo.inv() * Rotation.from_quat(q_hi[has])).as_rotvec()
            ori[has] = (r_lo * Rotation.from_rotvec(delta * alpha[has, None])).as_quat()
        pos[~placed] = np.nan
        return placed, pos, ori


def frame_order(frames: Sequence[str]) -> list[str]:
    """The order frames are tried in: :data:`~tactus_memory.where.DEFAULT_FRAME` first, then
    by name."""
    return sorted(set(frames), key=lambda f: (f != DEFAULT_FRAME, f))


def place_many(
    trajectories: Sequence[Trajectory], when: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """``when: (M,)`` -> (position ``(M, 3)``, orientation ``(M, 4)``, frame per item); NaN
    and None where no trajectory places the item (frames tried in :func:`frame_order`)."""
    m = np.asarray(when, dtype=np.float64)
    pos = np.full((m.size, 3), np.nan)
    ori = np.full((m.size, 4), np.nan)
    frames: list[str | None] = [None] * m.size
    todo = np.ones(m.size, dtype=bool)
    by_frame = {tr.frame: tr for tr in trajectories}
    for name in frame_order(list(by_frame)):
        if not todo.any():
            break
        idx = np.flatnonzero(todo)
        placed, p, o = by_frame[name].place(m[idx])
        got = idx[placed]
        pos[got], ori[got] = p[placed], o[placed]
        for i in got:
            frames[int(i)] = name
        todo[got] = False
    return pos, ori, frames


@dataclass
class Placement:
    """Where each of n items happened: ``position: (n, 3)`` and ``orientation: (n, 4)`` (NaN
    where unknown), ``frame`` and ``placed`` (``"given"``, ``"poses"`` or None) per item."""

    position: np.ndarray
    orientation: np.ndarray
    frame: list[str | None]
    placed: list[str | None]

    @classmethod
    def empty(cls, n: int) -> Placement:
        return cls(np.full((n, 3), np.nan), np.full((n, 4), np.nan), [None] * n, [None] * n)

    def unplaced_or_derived(self) -> np.ndarray:
        """Indices of the items not given a position (placed from poses, or not at all)."""
        return np.array([i for i, p in enumerate(self.placed) if p != "given"], dtype=np.int64)

    def set_from_poses(
        self, idx: np.ndarray, pos: np.ndarray, ori: np.ndarray, frames: list[str | None]
    ) -> None:
        """Items ``idx`` placed from the trajectory (``pos``/``ori``/``frames`` per index)."""
        for j, i in enumerate(idx):
            self.position[i], self.orientation[i] = pos[j], ori[j]
            self.frame[i] = frames[j]
            self.placed[i] = None if frames[j] is None else "poses"

    def columns(self) -> dict[str, Any]:
        """The items table's place columns (Arrow arrays, null where unknown)."""
        import pyarrow as pa

        known = np.isfinite(self.position).all(axis=1)
        has_ori = np.isfinite(self.orientation).all(axis=1)
        quats = pa.array(
            [
                list(map(float, q)) if h else None
                for q, h in zip(self.orientation, has_ori, strict=True)
            ],
            pa.list_(pa.float64(), 4),
        )
        out: dict[str, Any] = {
            c: pa.array(self.position[:, j], pa.float64(), mask=~known) for j, c in enumerate("xyz")
        }
        out.update(
            orientation=quats,
            frame=pa.array(self.frame, pa.string()),
            placed=pa.array(self.placed, pa.string()),
        )
        return out


def given_placement(n: int, position: Any, frame: str) -> Placement:
    """The explicit positions of an ``add_many`` call: one ``(x, y, z)`` for every item, or n
    entries (each ``(x, y, z)`` or None); ``frame`` (already checked) for the given ones."""
    out = Placement.empty(n)
    if position is None:
        return out
    try:
        flat = np.asarray(position, dtype=np.float64)
    except (TypeError, ValueError):
        flat = None
    if flat is not None and flat.shape == (3,):
        rows: list[Any] = [position] * n
    elif isinstance(position, (str, bytes)) or not hasattr(position, "__len__"):
        raise InvalidInputError(f"position must be (x, y, z) or one per item, got {position!r}")
    elif len(position) != n:
        raise InvalidInputError(f"position has {len(position)} entries for {n} items")
    else:
        rows = list(position)
    for i, p in enumerate(rows):
        if p is not None:
            out.position[i] = check_position(p, f"position {i}")
            out.frame[i] = frame
            out.placed[i] = "given"
    return out
