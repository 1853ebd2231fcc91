"""Temporal reasoning over the memory: last / first / count / before / after / timeline,
moments (hits of every sense grouped in time), episodes and per-stream clock offsets.

:class:`Temporal` is an object over the memory's public ranked-search call
(:class:`~tactus_memory.query.RankedSearch`: ``rank``, ``resolve_senses``): the query is
embedded once (:func:`~tactus_memory.query.embed_query`), each sense is searched with its
query transform and scored by its calibrated z-score, then time logic runs in Python. What
"a match" is and how matches group: :mod:`tactus_memory.matching`. ``Memory`` exposes every
operator with the usual keywords (``memory.count(q, session=..., senses=...)``).

**Clock offsets.** ``set_clock_offset(session, sense, offset, source)`` records that a stream's
clock runs ``offset`` seconds behind the session's reference clock: its items are placed at
``t + offset`` (``t_aligned``) for grouping, ordering and every ``after``/``before`` bound of
this module. Offsets live in the store's ``meta`` table (persisted, shared by processes).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from tactus_memory.clocks import clock_table, put_session_clock, session_clock
from tactus_memory.episodes import (
    EPISODE_MAX_GAP,
    EPISODE_MEAN_COS,
    EPISODE_MIN_COS,
    Episode,
    check_rule,
    representative,
    segment,
)
from tactus_memory.errors import InvalidInputError, NotFoundError
from tactus_memory.grasps import GraspRule, pool_grasps
from tactus_memory.limits import MAX_CLOCK_OFFSET, MAX_K
from tactus_memory.matching import (  # re-exported: `from tactus_memory.temporal import ...`
    CORROBORATION_BONUS,
    DEFAULT_MATCH_Z,
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    MATCH_CANDIDATES,
    MATCH_Z,
    MOMENT_MIN_Z,
    MOMENT_POOL_FACTOR,
    MOMENT_POOL_MIN,
    RELATIVE_KEEP,
    TIMELINE_MAX,
    Match,
    check_relative,
    check_seconds,
    group_moments,
    make_moment,
    match_flags,
    resolve_thresholds,
    sense_bar,
)

# re-exported (`X as X`): `from tactus_memory.temporal import Moment, ...` keeps working
from tactus_memory.models import ClockOffset as ClockOffset
from tactus_memory.models import Context as Context
from tactus_memory.models import Evidence as Evidence
from tactus_memory.models import Grasp, row_fields
from tactus_memory.models import Moment as Moment
from tactus_memory.models import Occurrences as Occurrences
from tactus_memory.models import Side as Side
from tactus_memory.models import TimelineItem as TimelineItem
from tactus_memory.query import RankedSearch, Scope, check_k, embed_query
from tactus_memory.senses import validate_sense_name
from tactus_memory.store import HIT_COLUMNS, Where, finite_float, validate_id
from tactus_memory.store import validate_source as _validate_source
from tactus_memory.vectors import vector_column

__all__ = [
    "CORROBORATION_BONUS",
    "DEFAULT_MATCH_Z",
    "DEFAULT_MERGE_GAP",
    "DEFAULT_MOMENT_GAP",
    "DEFAULT_WINDOW",
    "MATCH_CANDIDATES",
    "MATCH_Z",
    "MAX_CLOCK_OFFSET",
    "MOMENT_MIN_Z",
    "MOMENT_POOL_FACTOR",
    "MOMENT_POOL_MIN",
    "RELATIVE_KEEP",
    "TIMELINE_MAX",
    "ClockOffset",
    "Context",
    "Evidence",
    "Match",
    "Moment",
    "Occurrences",
    "Side",
    "Temporal",
    "TimelineItem",
    "check_relative",
    "check_seconds",
    "group_moments",
    "make_moment",
    "match_flags",
    "resolve_thresholds",
]

Offsets = Mapping[tuple[str, str, str], float]
#: the grasp rule a question groups by (None: items, not grasps)
Rule = GraspRule | None
EpisodeRule = tuple[float, float, float]  # episode rule: (min_cos, mean_cos, max_gap)


def _overlaps(item: TimelineItem | Episode, after: float | None, before: float | None) -> bool:
    return (after is None or item.t_end_aligned >= after) and (
        before is None or item.t_aligned <= before
    )


def _pad(offsets: Offsets, session: str | None) -> float:
    """How far store-side time bounds must be widened so no aligned item is missed."""
    vals = [abs(v) for (s, _, _), v in offsets.items() if session is None or s == session]
    return max(vals, default=0.0)


class Temporal:
    """Temporal operators, moments, episodes and clock offsets over one memory.

    Every question takes a :class:`~tactus_memory.query.Scope` (``senses`` None: every sense
    with rows; ``after``/``before`` with overlap semantics on the aligned clock) and, where
    it matches, a :class:`~tactus_memory.matching.Match` bar.
    """

    def __init__(self, memory: RankedSearch) -> None:
        self.memory = memory
        self.store = memory.store

    # ----------------------------------------------------------- clock offsets
    def offsets(self) -> dict[tuple[str, str, str], float]:
        """(session, sense, source) -> offset, for every recorded stream."""
        out: dict[tuple[str, str, str], float] = {}
        for session, streams in clock_table(self.store).items():
            for key, value in streams.items():
                sense, source = key.split("/", 1)
                out[(session, sense, source)] = float(value)
        return out

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock.

        Persisted in the store; ``offset=0`` removes the entry. The sense need not exist yet.
        """
        session = validate_id(session, "session id")
        sense = validate_sense_name(sense)
        source = _validate_source(source)
        value = finite_float(offset, "offset")
        if abs(value) > MAX_CLOCK_OFFSET:
            raise InvalidInputError(
                f"offset {value!r} is beyond +-{MAX_CLOCK_OFFSET:g} s; a clock offset is a "
                "time shift, and t + offset must stay a finite number"
            )
        with self.memory.lock:
            streams = session_clock(self.store, session)
            key = f"{sense}/{source}"
            if value == 0.0:
                streams.pop(key, None)
            else:
                streams[key] = value
            put_session_clock(self.store, session, streams)  # this session's row only

    def clock_offsets(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        if session is not None:  # one meta row, not every session's
            streams = session_clock(self.store, validate_id(session, "session id"))
            offsets = {(session, *k.split("/", 1)): float(v) for k, v in streams.items()}
        else:
            offsets = self.offsets()
        return [
            ClockOffset(session=s, sense=sense, source=source, offset=v)
            for (s, sense, source), v in sorted(offsets.items())
        ]

    # ----------------------------------------------------------- scoring
    def evidence(
        self, q: np.ndarray, scope: Scope, match: Match, per_sense: int, grasp: Rule = None
    ) -> tuple[list[Evidence], bool]:
        """Every candidate of the (1, D) query ``q`` (all senses in scope), scored and flagged;
        and whether a sense was capped (``per_sense`` candidates, all matching). With a
        ``grasp`` rule, the candidates' grasps (:mod:`tactus_memory.grasps`) instead, each
        scored and flagged by its pooled vector."""
        relative = check_relative(match.relative)
        offsets = self.offsets()
        base = scope.where(_pad(offsets, scope.session))
        after, before = scope.bounds()
        names = self.memory.resolve_senses(scope.senses)
        bars = resolve_thresholds(match.threshold, names)
        out: list[Evidence] = []
        capped = False
        for name in names:
            hits = self.memory.rank(q, per_sense, [name], base, transform=True)
            evs = []
            for h in hits:
                off = offsets.get((h.session, h.sense, h.source), 0.0)
                evs.append(
                    Evidence(
                        **h.model_dump(exclude={"score", "cosine", "match", "bar"}),
                        t_aligned=h.t + off,
                        t_end_aligned=h.t_end + off,
                        score=h.score,
                        cosine=h.cosine,
                    )
                )
            if grasp is not None:
                evs = pool_grasps(self.memory, q, name, evs, grasp)
            bar = sense_bar([e.score for e in evs], bars[name], relative)
            flags = [e.score >= bar for e in evs]
            capped = capped or (len(hits) >= per_sense and all(flags))
            for e, flag in zip(evs, flags, strict=True):
                e.match, e.bar = flag, bar
                if _overlaps(e, after, before):
                    out.append(e)
        return out, capped

    def matches(self, query: str, scope: Scope, match: Match, grasp: Rule = None) -> list[Evidence]:
        """Every item (with a ``grasp`` rule: every grasp) matching ``query`` (see
        :mod:`tactus_memory.matching`), in aligned time order."""
        q = embed_query(self.memory.space, query)
        ev, _ = self.evidence(q, scope, match, MATCH_CANDIDATES, grasp)
        return sorted((e for e in ev if e.match), key=lambda e: (e.t_aligned, e.sense, e.id))

    # ----------------------------------------------------------- last / first / count
    def occurrences(
        self,
        query: str,
        scope: Scope,
        match: Match,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
        grasp: Rule = None,
    ) -> Occurrences:
        """Distinct occurrences of ``query``: matching items (with a ``grasp`` rule: grasps,
        matched on their pooled score) merged per session when their aligned spans overlap or
        lie within ``merge_gap`` seconds. ``per_stream=True`` merges only within one stream
        (session + sense + source): a grasp and its note count twice."""
        gap = check_seconds(merge_gap, "merge_gap")
        q = embed_query(self.memory.space, query)
        ev, capped = self.evidence(q, scope, match, MATCH_CANDIDATES, grasp)
        moments = group_moments([e for e in ev if e.match], gap, per_stream=per_stream)
        return Occurrences(
            query=query, count=len(moments), capped=capped, merge_gap=gap, moments=moments
        )

    # ----------------------------------------------------------- before / after
    def around(
        self,
        side: Side,
        anchor: str,
        window: float,
        scope: Scope,
        match: Match,
        anchor_senses: Sequence[str] | None = None,
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``
        (items of its session that start in ``[a.t - window, a.t)``, aligned) or after it
        (``[a.t_end, a.t_end + window]``, the anchor excluded). The anchor is searched in
        ``anchor_senses`` within the scope's session, time bounds and place (near, frame);
        the items are of the scope's senses and source. None when nothing matches the
        anchor."""
        window = check_seconds(window, "window")
        names = None if scope.senses is None else self.memory.resolve_senses(scope.senses)
        anchor_scope = Scope(
            session=scope.session, senses=anchor_senses, after=scope.after, before=scope.before,
            near=scope.near, frame=scope.frame,
        )  # fmt: skip
        found = self.matches(anchor, anchor_scope, match)
        if not found:
            return None
        a = max(found, key=lambda e: (e.score, e.t_aligned, e.id))
        if side == "before":
            lo, hi = a.t_aligned - window, a.t_aligned
        else:
            lo, hi = a.t_end_aligned, a.t_end_aligned + window
        offsets = self.offsets()
        pad = _pad(offsets, a.session)
        where = (
            Where()
            .session(a.session)
            .t_range(lo - pad, None)
            .source(scope.source)
            .overlaps(before=hi + pad)
        )
        if names is not None:
            where.senses(names)
        items = [
            it
            for it in self._items(where, offsets)
            if it.id != a.id
            and lo <= it.t_aligned
            and (it.t_aligned < hi if side == "before" else it.t_aligned <= hi)
        ]
        return Context(side=side, window=window, anchor=a, t_from=lo, t_to=hi, items=items)

    # ----------------------------------------------------------- timeline
    def _items(self, where: Where, offsets: Offsets) -> list[TimelineItem]:
        rows = self.store.scan(where.sql(), HIT_COLUMNS, limit=TIMELINE_MAX + 1).to_pylist()
        if len(rows) > TIMELINE_MAX:
            raise InvalidInputError(
                f"more than {TIMELINE_MAX} items in range; narrow it with after/before or senses"
            )
        items = []
        for r in rows:
            off = offsets.get((r["session"], r["sense"], r.get("source") or ""), 0.0)
            items.append(
                TimelineItem(
                    **row_fields(r), t_aligned=r["t"] + off, t_end_aligned=r["t_end"] + off
                )
            )
        items.sort(key=lambda it: (it.t_aligned, it.t_end_aligned, it.sense, it.source, it.id))
        return items

    def timeline(
        self, scope: Scope, episodes: bool = False, limit: int | None = None
    ) -> list[TimelineItem] | list[Episode]:
        """The scope's session's items (or, with ``episodes=True``, its episodes) in aligned
        time order; ``limit`` keeps the first. Raises NotFoundError for an unknown session."""
        session = validate_id(scope.session, "session id")
        if limit is not None and (
            isinstance(limit, bool) or not isinstance(limit, int) or limit < 1
        ):
            raise InvalidInputError(f"limit must be a positive int, got {limit!r}")
        names = None if scope.senses is None else self.memory.resolve_senses(scope.senses)
        offsets = self.offsets()
        if self.store.count(Where().session(session).sql()) == 0:
            raise NotFoundError(f"no session {session!r}")
        after, before = scope.bounds()
        if episodes and (scope.near is not None or scope.frame is not None):
            raise InvalidInputError("near/frame select items, not episodes: drop one of them")
        if episodes:
            eps = self._episodes(session, names, scope.source)
            eps = [e for e in eps if _overlaps(e, after, before)]
            return eps[:limit] if limit else eps
        where = scope.where(_pad(offsets, session))
        if names is not None:
            where.senses(names)
        items = [it for it in self._items(where, offsets) if _overlaps(it, after, before)]
        return items[:limit] if limit else items

    # ----------------------------------------------------------- episodes
    def segment_episodes(
        self,
        session: str | None = None,
        *,
        min_cos: float = EPISODE_MIN_COS,
        mean_cos: float = EPISODE_MEAN_COS,
        max_gap: float = EPISODE_MAX_GAP,
    ) -> int:
        """Segment every stream of ``session`` (default: every session) into episodes and store
        the ids in the ``episode`` column; returns how many episodes were written.

        Rule: :func:`tactus_memory.episodes.segment`. Episode ids are unique within a session,
        numbered 0, 1, ... by (first item's time, sense, source); re-running is idempotent.
        """
        check_rule(min_cos, mean_cos, max_gap)
        if session is None:
            sessions = self.memory.session_ids()
        else:
            sessions = [validate_id(session, "session id")]
        total = 0
        for sid in sessions:
            ids, episode = self._segment(sid, (min_cos, mean_cos, max_gap))
            if not ids:
                if session is not None:
                    raise NotFoundError(f"no session {sid!r}")
                continue
            with self.memory.lock:
                self.store.set_episodes(ids, episode)
            total += int(episode.max()) + 1
        return total

    def _segment(
        self, session: str, rule: EpisodeRule | None = None
    ) -> tuple[list[str], np.ndarray]:
        """(ids, (N,) int64 episode numbers) of every row of ``session`` under ``rule``
        (min_cos, mean_cos, max_gap), computed, not stored: numbered 0, 1, ... by (first
        item's time, sense, source)."""
        min_cos, mean_cos, max_gap = rule or (EPISODE_MIN_COS, EPISODE_MEAN_COS, EPISODE_MAX_GAP)
        cols = ["id", "sense", "source", "t", "t_end", "vector"]
        tbl = self.store.scan(Where().session(session).sql(), cols)
        ids = tbl.column("id").to_pylist()
        if not ids:
            return [], np.zeros(0, dtype=np.int64)
        firsts: list[tuple[float, str, str, int, np.ndarray]] = []
        vecs = vector_column(tbl, self.memory.space.dim)
        t = tbl.column("t").to_numpy()
        t_end = tbl.column("t_end").to_numpy()
        for (sense, source), idx in sorted(_streams(tbl).items()):
            labels = segment(
                t[idx], t_end[idx], vecs[idx], min_cos=min_cos, mean_cos=mean_cos,
                max_gap=max_gap,
            )  # fmt: skip
            for lab in np.unique(labels):
                members = idx[labels == lab]
                firsts.append((float(t[members[0]]), sense, source, int(lab), members))
        firsts.sort(key=lambda f: (f[0], f[1], f[2], f[3]))
        episode = np.zeros(len(ids), dtype=np.int64)
        for number, (*_, members) in enumerate(firsts):
            episode[members] = number
        return ids, episode

    def episodes(
        self, session: str, *, senses: Sequence[str] | None = None, source: str | None = None
    ) -> list[Episode]:
        """The session's episodes in aligned time order: the stored ones (segment_episodes),
        or, while some rows have none, computed now and not stored (reads never write)."""
        session = validate_id(session, "session id")
        if self.store.count(Where().session(session).sql()) == 0:
            raise NotFoundError(f"no session {session!r}")
        return self._episodes(session, senses, source)

    def _episodes(
        self, session: str, senses: Sequence[str] | None, source: str | None
    ) -> list[Episode]:
        """:meth:`episodes` of a validated session known to have rows."""
        where = Where().session(session)
        unsegmented = Where().session(session)
        unsegmented.parts.append("episode IS NULL")
        computed: dict[str, int] | None = None
        if self.store.count(unsegmented.sql()) > 0:
            ids_all, numbers = self._segment(session)
            computed = dict(zip(ids_all, numbers.tolist(), strict=True))
        if senses is not None:
            where.senses(self.memory.resolve_senses(senses))
        where.source(source)
        cols = ["id", "sense", "source", "t", "t_end", "episode", "vector"]
        tbl = self.store.scan(where.sql(), cols)
        offsets = self.offsets()
        if tbl.num_rows == 0:
            return []
        vecs = vector_column(tbl, self.memory.space.dim)
        ids = tbl.column("id").to_pylist()
        senses_col = tbl.column("sense").to_pylist()
        sources = [s or "" for s in tbl.column("source").to_pylist()]
        t = tbl.column("t").to_numpy()
        t_end = tbl.column("t_end").to_numpy()
        if computed is None:
            ep = tbl.column("episode").to_numpy()
        else:
            late = max(computed.values(), default=-1) + 1  # rows written since: one more
            ep = np.array([computed.get(i, late) for i in ids], dtype=np.int64)
        out = []
        # one sort by (episode, t, id), split where the episode changes: rows of each episode
        # in (t, id) order, episodes ascending
        order = np.lexsort((np.array(ids, dtype=object), t, ep))
        starts = np.flatnonzero(np.diff(ep[order])) + 1
        for members in np.split(order, starts):
            first = members[0]
            number = ep[first]
            off = offsets.get((session, senses_col[first], sources[first]), 0.0)
            rep = members[representative(vecs[members])]
            out.append(
                Episode(
                    session=session,
                    sense=senses_col[first],
                    source=sources[first],
                    episode=int(number),
                    t=float(t[members].min()),
                    t_end=float(t_end[members].max()),
                    t_aligned=float(t[members].min()) + off,
                    t_end_aligned=float(t_end[members].max()) + off,
                    n=len(members),
                    representative=ids[rep],
                )
            )
        out.sort(key=lambda e: (e.t_aligned, e.sense, e.source, e.episode))
        return out

    # ----------------------------------------------------------- moments
    def moments(
        self,
        q: np.ndarray,
        k: int,
        scope: Scope,
        match: Match,
        gap: float = DEFAULT_MOMENT_GAP,
        grasp: Rule = None,
    ) -> list[Moment]:
        """Search with the (1, D) query embedding ``q``, then group hits of one session whose
        aligned spans overlap or lie within ``gap`` seconds into moments carrying every
        sense's evidence; best ``k`` moments.

        Candidates: the top max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN) per sense that score
        at least MOMENT_MIN_Z (above the sense's null mean); with a ``grasp`` rule, their
        grasps. Score: see :class:`Moment`.
        """
        k = check_k(k)
        gap = check_seconds(gap, "gap")
        pool = min(MAX_K, max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN))
        ev, _ = self.evidence(q, scope, match, pool, grasp)
        moments = group_moments([e for e in ev if e.match or e.score >= MOMENT_MIN_Z], gap)
        moments.sort(key=lambda m: (-m.score, m.t, m.session))
        return moments[:k]

    def grasps(self, q: np.ndarray, k: int, scope: Scope, rule: GraspRule) -> list[Grasp]:
        """Search ranked by grasp: the top max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN)
        windows per sense, grouped into their grasps, best ``k`` grasps by pooled score."""
        pool = min(MAX_K, max(check_k(k) * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN))
        ev, _ = self.evidence(q, scope, Match(), pool, rule)
        return sorted(ev, key=lambda g: (-g.score, g.t_aligned, g.id))[:k]  # type: ignore[return-value]


def _streams(tbl: Any) -> dict[tuple[str, str], np.ndarray]:
    """(sense, source) -> row indices sorted by (t, id)."""
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
