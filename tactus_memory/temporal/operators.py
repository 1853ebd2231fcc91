"""Temporal reasoning over the memory: last / first / count / before / after / timeline,
moments (hits of every sense grouped in time), episodes and per-stream clock offsets.

:class:`Temporal` is built from the parts it needs: the store (rows, episodes), the sense
registry (which senses a scope covers), the ranker (the one ranked search path,
:class:`~tactus_memory.search.ranking.Ranker`), the space (query embedding) and the write lock.
The query is embedded once (:func:`~tactus_memory.query.embed_query`); every sense in scope
is ranked in one Ranker pass and grasps are grouped after it
(:func:`~tactus_memory.search.evidence.ranked_evidence`), each sense's matches flagged by its
bar; then time logic runs in Python. What "a match" is and how matches group:
:mod:`tactus_memory.matching`; clock offsets: :mod:`tactus_memory.temporal.clocks`.

Every question takes the scope as keywords (``session``, ``senses``, ``source``, ``after``,
``before``, ``near``, ``frame``, or one ``scope=``) and, where it matches, the match bar
(``threshold``, ``relative``, or one ``match=``); ``group="grasp"`` (with ``pool``) asks it
of grasps, not windows (:mod:`tactus_memory.search.grasps`). ``Memory`` answers each with
the same method (``memory.count(q, session=...)`` is ``memory.temporal.count``), and so does
the service.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from typing_extensions import Unpack

from tactus_memory.errors import InvalidInputError, NotFoundError
from tactus_memory.limits import MAX_K
from tactus_memory.matching import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    GRASP_MATCH_Z,
    MATCH_CANDIDATES,
    MOMENT_MIN_Z,
    MOMENT_POOL_FACTOR,
    MOMENT_POOL_MIN,
    AroundKwargs,
    Match,
    MatchKwargs,
    OccurrenceKwargs,
    answering,
    check_relative,
    check_seconds,
    group_moments,
    resolve_thresholds,
    sense_bar,
    split_match,
)
from tactus_memory.names import validate_id
from tactus_memory.query import Scope, TimelineKwargs, check_k, embed_query, timeline_scope
from tactus_memory.results import (
    ClockOffset,
    Context,
    Episode,
    Evidence,
    Grasp,
    Hit,
    Moment,
    Occurrences,
    Side,
    Timeline,
)
from tactus_memory.search.evidence import ranked_evidence
from tactus_memory.search.grasps import (
    DEFAULT_GROUP,
    GRASP_MODALITY,
    OCCURRENCE_POOL,
    GraspRule,
    as_hit,
    grasp_rule,
)
from tactus_memory.search.ordering import candidates, check_order, sort_hits
from tactus_memory.search.ranking import Ranker
from tactus_memory.senses.stored import SenseRegistry
from tactus_memory.spaces.base import Space
from tactus_memory.storage.store import Store
from tactus_memory.temporal.clocks import Clocks, pad
from tactus_memory.temporal.episodes import (
    EPISODE_MAX_GAP,
    EPISODE_MEAN_COS,
    EPISODE_MIN_COS,
    EpisodeRule,
    check_rule,
    number_episodes,
    representative,
)
from tactus_memory.temporal.timeline import overlaps, timeline_items
from tactus_memory.vectors import vector_column
from tactus_memory.where import Where

#: the grasp rule a question groups by (None: items, not grasps)
Rule = GraspRule | None


@dataclass(eq=False)
class Temporal:
    """Temporal operators, moments, episodes and clock offsets over one store.

    ``after``/``before`` use overlap semantics on the aligned clock; ``senses`` None means
    every sense with rows.
    """

    store: Store
    registry: SenseRegistry
    ranker: Ranker
    space: Space
    lock: threading.RLock

    def __post_init__(self) -> None:
        self.clocks = Clocks(self.store, self.lock)

    # ----------------------------------------------------------- clock offsets
    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock
        (persisted; ``offset=0`` removes it; see :mod:`tactus_memory.temporal.clocks`)."""
        self.clocks.set(session, sense, offset, source)

    def clock_offsets(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        return self.clocks.listed(session)

    # ----------------------------------------------------------- scoring
    def _evidence(
        self, q: np.ndarray, scope: Scope, match: Match, per_sense: int, grasp: Rule = None
    ) -> tuple[list[Evidence], bool]:
        """Every candidate of the (1, D) query ``q`` (all senses in scope), scored and flagged;
        and whether a sense was capped (``per_sense`` candidates, all matching). With a
        ``grasp`` rule, the candidates' grasps (:mod:`tactus_memory.search.grasps`) instead, each
        scored and flagged by its pooled vector. One view of the senses for the whole question
        (:meth:`SenseRegistry.pinned`), however many senses it ranks."""
        with self.registry.pinned():
            return self._scored(q, scope, match, per_sense, grasp)

    def _scored(
        self, q: np.ndarray, scope: Scope, match: Match, per_sense: int, grasp: Rule
    ) -> tuple[list[Evidence], bool]:
        relative = check_relative(match.relative)
        offsets = self.clocks.offsets()
        base = scope.where(pad(offsets, scope.session))
        after, before = scope.bounds()
        names = self.registry.resolve(scope.senses)
        bars = resolve_thresholds(match.threshold, names)
        out: list[Evidence] = []
        capped = False
        for found in ranked_evidence(self.ranker, q, names, base, per_sense, offsets, grasp):
            evs, floor = found.evidence, bars[found.sense]
            if (
                found.grouped
                and match.threshold is None
                and grasp is not None
                and grasp.pool != "max"
            ):
                floor = GRASP_MATCH_Z.get(found.sense, floor)  # pooled grasps: their own bar
            bar = sense_bar([e.score for e in evs], floor, relative)
            flags = [e.score >= bar for e in evs]
            capped = capped or (found.ranked >= per_sense and all(flags))
            for e, flag in zip(evs, flags, strict=True):
                e.match, e.bar = flag, bar
                if overlaps(e, after, before):
                    out.append(e)
        return out, capped

    def matches(self, query: str, **kw: Unpack[MatchKwargs]) -> list[Evidence]:
        """Every item matching ``query`` (see :mod:`tactus_memory.matching`), in aligned time
        order."""
        return self._matches(query, *split_match(kw))

    def _matches(self, query: str, scope: Scope, match: Match) -> list[Evidence]:
        q = embed_query(self.space, query)
        ev, _ = self._evidence(q, scope, match, MATCH_CANDIDATES)
        return sorted((e for e in ev if e.match), key=lambda e: (e.t_aligned, e.sense, e.id))

    # ----------------------------------------------------------- last / first / count
    def occurrences(
        self,
        query: str,
        *,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
        group: str | None = DEFAULT_GROUP,
        pool: str = OCCURRENCE_POOL,
        sort: str | None = None,
        **kw: Unpack[MatchKwargs],
    ) -> Occurrences:
        """Distinct occurrences of ``query``: matching items (``group="grasp"``: grasps,
        matched on their ``pool`` score) merged per session when their aligned spans overlap
        or lie within ``merge_gap`` seconds. ``per_stream=True`` merges only within one
        stream (session + sense + source): a grasp and its note count twice. The
        occurrences come in time order, or in ``sort`` order (a touch facet, or ``-t``:
        :mod:`tactus_memory.search.ordering`); the order never changes which occurrences
        answer, so ``count`` is the same whatever it is, and ``first``/``last`` are the two
        ends of it: ``first(q, sort="-force")`` is the firmest occurrence."""
        scope, match = split_match(kw)
        gap = check_seconds(merge_gap, "merge_gap")
        rule = grasp_rule(group, pool)
        check_order(sort, scope, self.store.schema)
        q = embed_query(self.space, query)
        ev, capped = self._evidence(q, scope, match, MATCH_CANDIDATES, rule)
        passed = group_moments([e for e in ev if e.match], gap, per_stream=per_stream)
        moments = sort_hits(answering(passed, match.answer), sort, len(passed))
        return Occurrences(
            query=query, count=len(moments), capped=capped, merge_gap=gap, moments=moments,
            passed=len(passed), answer=match.answer, sort=sort,
        )  # fmt: skip

    def count(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> int:
        """How many distinct times ``query`` happened (see :meth:`occurrences`)."""
        return self.occurrences(query, **kw).count

    def last(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The most recent occurrence of ``query`` (latest aligned start), or None."""
        moments = self.occurrences(query, **kw).moments
        return moments[-1] if moments else None

    def first(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The earliest occurrence of ``query`` (earliest aligned start), or None."""
        moments = self.occurrences(query, **kw).moments
        return moments[0] if moments else None

    # ----------------------------------------------------------- before / after
    def before(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``: items
        of its session that start in ``[a.t - window, a.t)`` (aligned). The anchor is searched
        in ``anchor_senses`` within the scope's session, time bounds and place (near, frame);
        the items are of the scope's senses and source. None when nothing matches the
        anchor."""
        return self._around("before", anchor, window, dict(kw))

    def after(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor``: items
        that start in ``[a.t_end, a.t_end + window]``, the anchor excluded (as :meth:`before`)."""
        return self._around("after", anchor, window, dict(kw))

    def _around(self, side: Side, anchor: str, window: float, kw: dict[str, Any]) -> Context | None:
        anchor_senses = kw.pop("anchor_senses", None)
        scope, match = split_match(kw)
        window = check_seconds(window, "window")
        names = None if scope.senses is None else self.registry.resolve(scope.senses)
        anchor_scope = Scope(
            session=scope.session, senses=anchor_senses, after=scope.after, before=scope.before,
            near=scope.near, frame=scope.frame,
        )  # fmt: skip
        found = self._matches(anchor, anchor_scope, match)
        if not found:
            return None
        a = max(found, key=lambda e: (e.score, e.t_aligned, e.id))
        if side == "before":
            lo, hi = a.t_aligned - window, a.t_aligned
        else:
            lo, hi = a.t_end_aligned, a.t_end_aligned + window
        offsets = self.clocks.offsets()
        wide = pad(offsets, a.session)
        where = (
            Where()
            .session(a.session)
            .t_range(lo - wide, None)
            .source(scope.source)
            .overlaps(before=hi + wide)
        )
        if names is not None:
            where.senses(names)
        items = [
            it
            for it in timeline_items(self.store, where, offsets)
            if it.id != a.id
            and lo <= it.t_aligned
            and (it.t_aligned < hi if side == "before" else it.t_aligned <= hi)
        ]
        return Context(side=side, window=window, anchor=a, t_from=lo, t_to=hi, items=items)

    # ----------------------------------------------------------- timeline
    def timeline(self, session: str, **kw: Unpack[TimelineKwargs]) -> Timeline:
        """The session's items (or, with ``episodes=True``, its episodes) in aligned time
        order; the keywords (:class:`~tactus_memory.query.TimelineKwargs`): ``senses``,
        ``after``/``before`` with overlap semantics on the aligned clock, ``source``,
        ``near`` / ``frame`` keep the items placed there (not episodes), ``limit`` keeps the
        first. Raises NotFoundError for an unknown session."""
        session = validate_id(session, "session id")
        scope, limit = timeline_scope(session, kw)
        episodes = bool(kw.get("episodes", False))
        names = None if scope.senses is None else self.registry.resolve(scope.senses)
        offsets = self.clocks.offsets()
        if self.store.count(Where().session(session).sql()) == 0:
            raise NotFoundError(f"no session {session!r}")
        after, before = scope.bounds()
        if episodes and (scope.near is not None or scope.frame is not None):
            raise InvalidInputError("near/frame select items, not episodes: drop one of them")
        if episodes:
            eps = self._episodes(session, names, scope.source)
            eps = [e for e in eps if overlaps(e, after, before)]
            return eps[:limit] if limit else eps
        where = scope.where(pad(offsets, session))
        if names is not None:
            where.senses(names)
        items = timeline_items(self.store, where, offsets)
        items = [it for it in items if overlaps(it, after, before)]
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

        Rule: :func:`tactus_memory.temporal.episodes.segment`. Episode ids are unique within a
        session,
        numbered 0, 1, ... by (first item's time, sense, source); re-running is idempotent.
        """
        check_rule(min_cos, mean_cos, max_gap)
        if session is None:
            col = self.store.scan(None, ["session"]).column("session")
            sessions = sorted(set(col.to_pylist()))
        else:
            sessions = [validate_id(session, "session id")]
        total = 0
        for sid in sessions:
            ids, episode = self._segment(sid, (min_cos, mean_cos, max_gap))
            if not ids:
                if session is not None:
                    raise NotFoundError(f"no session {sid!r}")
                continue
            with self.lock:
                self.store.set_episodes(ids, episode)
            total += int(episode.max()) + 1
        return total

    def _segment(
        self, session: str, rule: EpisodeRule = (EPISODE_MIN_COS, EPISODE_MEAN_COS, EPISODE_MAX_GAP)
    ) -> tuple[list[str], np.ndarray]:
        """(ids, (N,) int64 episode numbers) of every row of ``session`` under ``rule``,
        computed, not stored (:func:`~tactus_memory.temporal.episodes.number_episodes`)."""
        cols = ["id", "sense", "source", "t", "t_end", "vector"]
        tbl = self.store.scan(Where().session(session).sql(), cols)
        return number_episodes(tbl, self.space.dim, rule)

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
            where.senses(self.registry.resolve(senses))
        where.source(source)
        cols = ["id", "sense", "source", "t", "t_end", "episode", "vector"]
        tbl = self.store.scan(where.sql(), cols)
        offsets = self.clocks.offsets()
        if tbl.num_rows == 0:
            return []
        vecs = vector_column(tbl, self.space.dim)
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
    def search_moments(
        self,
        query: str,
        k: int = 10,
        *,
        gap: float = DEFAULT_MOMENT_GAP,
        group: str | None = DEFAULT_GROUP,
        pool: str = "mean",
        sort: str | None = None,
        **kw: Unpack[MatchKwargs],
    ) -> list[Moment]:
        """Search for ``query``, then group hits of one session whose aligned spans overlap
        or lie within ``gap`` seconds into moments carrying every sense's evidence; best
        ``k`` moments (:meth:`moments`); ``group="grasp"``: moments of grasps (pooled, with
        ``pool``), not of single windows. ``sort``: the best moments (at least
        ``search.ordering.SORT_CANDIDATES``) in that order, the first ``k``."""
        scope, match = split_match(kw)
        kk = candidates(check_k(k), sort, scope, self.store.schema)
        q = embed_query(self.space, query)
        found = self.moments(q, kk, scope, match, gap, grasp_rule(group, pool))
        return sort_hits(found, sort, k)

    def moments(
        self, q: np.ndarray, k: int, scope: Scope, match: Match, gap: float, grasp: Rule = None
    ) -> list[Moment]:
        """:meth:`search_moments` of the (1, D) query embedding ``q``. Candidates: the top
        max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN) per sense that score at least
        MOMENT_MIN_Z (above the sense's null mean); with a ``grasp`` rule, their grasps.
        Score: see :class:`Moment`."""
        k = check_k(k)
        gap = check_seconds(gap, "gap")
        pool = min(MAX_K, max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN))
        ev, _ = self._evidence(q, scope, match, pool, grasp)
        moments = group_moments([e for e in ev if e.match or e.score >= MOMENT_MIN_Z], gap)
        moments.sort(key=lambda m: (-m.score, m.t, m.session))
        return moments[:k]

    def grouped(
        self,
        q: np.ndarray,
        k: int,
        scope: Scope,
        group: str | None,
        pool: str,
        sort: str | None,
        first: int,
    ) -> list[Grasp] | list[Hit] | None:
        """``search(group=...)`` of the (1, D) query ``q``, ``k`` candidates in ``sort`` order
        (``search.ordering``), the ``first`` kept: ``"grasp"`` grasps of every sense; ``"auto"``
        with a touch sense in scope its grasps beside the other senses' items, as Hits. None
        for ``"window"`` or ``"auto"`` without touch (the merged top k answers)."""
        if group == "grasp":
            return sort_hits(self.grasps(q, k, scope, GraspRule(pool=pool)), sort, first)
        if group != "auto":
            return None
        names = self.registry.resolve(scope.senses)
        if all(self.registry.search_sense(n).modality != GRASP_MODALITY for n in names):
            return None
        rule = GraspRule(pool=pool, modality=GRASP_MODALITY)  # touch grasps, others items
        return sort_hits([as_hit(e) for e in self.grasps(q, k, scope, rule)], sort, first)

    def grasps(self, q: np.ndarray, k: int, scope: Scope, rule: GraspRule) -> list[Grasp]:
        """Search ranked by grasp: the top max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN)
        windows per sense, grouped into their grasps, best ``k`` grasps by pooled score."""
        pool = min(MAX_K, max(check_k(k) * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN))
        ev, _ = self._evidence(q, scope, Match(), pool, rule)
        return sorted(ev, key=lambda g: (-g.score, g.t_aligned, g.id))[:k]  # type: ignore[return-value]
