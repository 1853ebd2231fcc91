"""Where things happened: session trajectories in, items placed on them, questions by place.

:class:`Places` is built from the parts it needs (store, write lock, sense registry, space,
temporal operators); its public methods ARE ``memory.add_poses``, ``memory.where``, ...

``memory.add_poses(session, t, position, orientation=None, frame="map", source=None)`` stores
a trajectory (checked by :func:`tactus_memory.storage.places.check_poses`, one commit) and then
places
the session's items that it covers (backfill: poses may arrive before or after the items).
New items are placed as they are written (:meth:`Places.fill`, inside the memory's commit).
Placing uses the item's *aligned* time (``t + clock offset``); set clock offsets before poses
arrive, or call ``memory.place_items(session)`` after changing one.

``memory.where(q, ...)``: the places where moments matching ``q`` happened, best first.
``memory.at((x, y, z), radius, ...)``: what happened near a place, in time order. Every
search and temporal question also takes ``near=((x, y, z), radius)`` and ``frame=`` through
its :class:`~tactus_memory.query.Scope`.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from typing_extensions import Unpack

from tactus_memory.errors import InvalidInputError, PoseConflictError
from tactus_memory.limits import MAX_K
from tactus_memory.matching import DEFAULT_MOMENT_GAP, TIMELINE_MAX, MatchKwargs, split_match
from tactus_memory.names import validate_id
from tactus_memory.query import Scope, embed_query
from tactus_memory.results import Place, TimelineItem, TrajectoryOut, row_fields
from tactus_memory.storage.places import POSE_TOLERANCE, Placement, check_poses, place_many
from tactus_memory.storage.posestore import PoseStore
from tactus_memory.storage.tables import HIT_COLUMNS
from tactus_memory.temporal.clocks import pad, session_clock
from tactus_memory.where import (
    DEFAULT_FRAME,
    Near,
    Where,
    check_near,
    validate_frame,
    validate_source,
)

if TYPE_CHECKING:
    from tactus_memory.senses.stored import SenseRegistry
    from tactus_memory.spaces.base import Space
    from tactus_memory.storage.rows import PreparedWrite
    from tactus_memory.storage.store import Store
    from tactus_memory.temporal.operators import Temporal

#: ``where`` groups this many times k moments before dropping the unplaced ones
WHERE_POOL_FACTOR = 4


def _stream_offsets(store: Store, session: str) -> dict[str, float]:
    """ "sense/source" -> clock offset of one session."""
    return {k: float(v) for k, v in session_clock(store, session).items()}


@dataclass(eq=False)
class Places:
    """Trajectories, placing and the questions by place over one store."""

    store: Store
    lock: threading.RLock
    registry: SenseRegistry
    space: Space
    temporal: Temporal

    def __post_init__(self) -> None:
        self.poses = PoseStore(self.store)  # adds the place columns to an old store

    def add_poses(
        self,
        session: str,
        t: Any,
        position: Any,
        orientation: Any = None,
        frame: str = DEFAULT_FRAME,
        source: str | None = None,
    ) -> int:
        """Store a trajectory: ``t: (N,)`` strictly increasing seconds on the session clock,
        ``position: (N, 3)`` metres in ``frame``, ``orientation: (N, 4)`` unit quaternions
        (x, y, z, w) or None; returns the number of poses. Items the poses cover are placed
        (also those already stored). Raises InvalidInputError naming the problem (NaN,
        unsorted or duplicate times, non-unit quaternions, mismatched lengths); nothing is
        written then."""
        session = validate_id(session, "session id")
        frame = validate_frame(frame)
        source = validate_source(source or "")
        ts, pos, ori = check_poses(t, position, orientation)
        with self.lock:
            stored = [tr.t for tr in self.poses.trajectories(session) if tr.frame == frame]
            again = np.intersect1d(ts, np.concatenate(stored)) if stored else ts[:0]
            if again.size:
                shown = ", ".join(f"{x:g}" for x in again[:10])
                more = f" and {again.size - 10} more" if again.size > 10 else ""
                raise PoseConflictError(
                    f"session {session!r} already has poses in frame {frame!r} at t = "
                    f"{shown}{more}: poses are never replaced; delete the session's poses "
                    "or send only new times"
                )
            self.poses.write(session, ts, pos, ori, frame, source)
            self.place_items(session, float(ts[0]), float(ts[-1]))
        return int(ts.shape[0])

    def fill(self, writes: Sequence[PreparedWrite]) -> None:
        """Place the items of ``writes`` that were not given a position, from their session's
        trajectory (call under the memory's lock, just before the commit)."""
        for w in writes:
            idx = w.batch.place.unplaced_or_derived()
            trajectories = self.poses.trajectories(w.session) if idx.size else []
            if not trajectories:
                continue
            off = _stream_offsets(self.store, w.session).get(f"{w.sense.name}/{w.source}", 0.0)
            mid = (np.asarray(w.batch.t) + np.asarray(w.batch.t_end)) / 2 + off
            pos, ori, frames = place_many(trajectories, mid[idx])
            w.batch.place.set_from_poses(idx, pos, ori, frames)

    def place_items(self, session: str, lo: float | None = None, hi: float | None = None) -> int:
        """(Re)place the session's items that were not given a position (after a clock offset
        changed; those whose aligned middle time lies in ``[lo, hi]`` widened by
        POSE_TOLERANCE; default all); returns how many items changed place. One merge-insert
        commit."""
        session = validate_id(session, "session id")
        with self.lock:
            trajectories = self.poses.trajectories(session)
            offsets = _stream_offsets(self.store, session)
            widen = POSE_TOLERANCE + max((abs(v) for v in offsets.values()), default=0.0)
            where = Where().session(session)
            where.parts.append("placed IS NULL OR placed <> 'given'")
            if lo is not None and hi is not None:
                where.overlaps(lo - widen, hi + widen)
            cols = ["id", "sense", "source", "t", "t_end", "x", "y", "z", "frame"]
            tbl = self.store.scan(where.sql(), cols)
            if tbl.num_rows == 0:
                return 0
            rows = tbl.to_pylist()
            mid = np.array(
                [(r["t"] + r["t_end"]) / 2 + offsets.get(f"{r['sense']}/{r['source']}", 0.0)
                 for r in rows]
            )  # fmt: skip
            place = Placement.empty(len(rows))
            pos, ori, frames = place_many(trajectories, mid)
            place.set_from_poses(np.arange(len(rows)), pos, ori, frames)
            old = np.array([[np.nan if r[c] is None else r[c] for c in "xyz"] for r in rows])
            same_pos = np.isclose(old, pos, equal_nan=True).all(axis=1)
            changed = [i for i, r in enumerate(rows) if not same_pos[i] or r["frame"] != frames[i]]
            if changed:
                sub = Placement(
                    place.position[changed], place.orientation[changed],
                    [place.frame[i] for i in changed], [place.placed[i] for i in changed],
                )  # fmt: skip
                self.poses.set_places([rows[i]["id"] for i in changed], sub)
            return len(changed)

    def delete_session(self, session: str) -> int:
        """Forget the poses of ``session`` (its items were deleted); returns how many."""
        with self.lock:
            return self.poses.delete_session(session)

    def trajectory(self, session: str, frame: str | None = None) -> list[TrajectoryOut]:
        """The session's poses, one trajectory per frame, in time order (what the page and
        exports draw)."""
        session = validate_id(session, "session id")
        frame = None if frame is None else validate_frame(frame)
        return [
            TrajectoryOut(
                session=session,
                frame=tr.frame,
                t=tr.t.tolist(),
                position=tr.position.tolist(),
                orientation=None
                if not np.isfinite(tr.orientation).all()
                else tr.orientation.tolist(),
            )
            for tr in self.poses.trajectories(session)
            if frame is None or tr.frame == frame
        ]

    def where(
        self,
        query: str,
        k: int = 10,
        *,
        gap: float = DEFAULT_MOMENT_GAP,
        **kw: Unpack[MatchKwargs],
    ) -> list[Place]:
        """Where moments matching ``query`` happened, best first: each place is the moment's
        position (its best placed member's), with the moment's span, score and evidence.
        Keywords: the scope (session, senses, source, after, before, near, frame) and the
        match bar. Moments none of whose members is placed are left out."""
        scope, match = split_match(kw)
        pool = min(MAX_K, max(1, int(k)) * WHERE_POOL_FACTOR)
        moments = self.temporal.moments(embed_query(self.space, query), pool, scope, match, gap)
        out = [
            Place(
                session=m.session,
                position=m.position,
                frame=m.frame or "",
                t=m.t,
                t_end=m.t_end,
                score=m.score,
                senses=m.senses,
                best=m.best,
                evidence=m.hits,
            )  # fmt: skip
            for m in moments
            if m.position is not None
        ]
        return out[: max(1, int(k))]

    def at(
        self,
        position: Sequence[float],
        radius: float,
        *,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        senses: Sequence[str] | None = None,
        source: str | None = None,
        frame: str | None = None,
    ) -> list[TimelineItem]:
        """What happened within ``radius`` of ``position`` (in ``frame``, default any), in
        aligned time order (``after``/``before`` with overlap semantics). At most
        TIMELINE_MAX items; more raise InvalidInputError (narrow the scope)."""
        near: Near = check_near((position, radius))
        scope = Scope(session, senses, source, after, before, near, frame)
        lo, hi = scope.bounds()
        offsets = self.temporal.clocks.offsets()
        where = scope.where(pad(offsets, scope.session))
        if senses is not None:
            where.senses(self.registry.resolve(senses))
        rows = self.store.scan(where.sql(), HIT_COLUMNS, limit=TIMELINE_MAX + 1).to_pylist()
        if len(rows) > TIMELINE_MAX:
            raise InvalidInputError(
                f"more than {TIMELINE_MAX} items near that place; narrow it with a smaller "
                "radius, session, after/before or senses"
            )
        items = []
        for r in rows:
            off = offsets.get((r["session"], r["sense"], r.get("source") or ""), 0.0)
            it = TimelineItem(
                **row_fields(r), t_aligned=r["t"] + off, t_end_aligned=r["t_end"] + off
            )
            if (lo is None or it.t_end_aligned >= lo) and (hi is None or it.t_aligned <= hi):
                items.append(it)
        items.sort(key=lambda it: (it.t_aligned, it.t_end_aligned, it.session, it.sense, it.id))
        return items
