"""Temporal reasoning over the memory: last / first / count / before / after / timeline,
moments (hits of every sense grouped in time), episodes and per-stream clock offsets.

Everything here is deterministic (no LLM) and built on the memory's own search path: the query
is embedded once, each sense is searched with its query transform and scored by its calibrated
z-score (:mod:`tactus_memory.scoring`), then time logic runs in Python.

**What "a match" is.** A hit of sense *s* matches a query when

1. ``score >= threshold[s]``: its calibrated score (null standard deviations above the cosine
   that the generic probe queries get against *s*) clears an absolute, per-sense bar
   (:data:`MATCH_Z`, overridable per call with ``threshold=``). This is what makes an
   irrelevant query match *nothing*: a relative gate alone (e.g. "the top half of the
   candidates", as min-max normalised relevance does) always finds something.
2. ``score >= relative * best[s]``: it is also close to the best hit *of its own sense* for
   this query (``relative`` = :data:`RELATIVE_KEEP`; 0 disables it). This drops near misses
   that share words or texture with the real thing ("picked up the screwdriver" for "picked
   up the mug") once the real thing is in the memory. Per sense, so a strong note never
   suppresses a weaker but genuine touch match.

How the defaults were chosen (measured, real MiniLM + the shipped touch checkpoint):

* text (MiniLM notes): exact notes score 6-9, paraphrases ("holding a coffee cup" for
  "picked up the mug") about 3.4, unrelated queries at most 1.6 (generic ones such as
  "an object" 1.2) -> 3.0. The near miss "picked up the screwdriver" scores 3.1 for
  "picked up the mug" against 8.6 for the real notes: the relative gate removes it.
* touch (all 1,445 8-frame windows of the STAG ``weights`` subset, grasps and transitions):
  seven unrelated queries ("the weather in paris", "stock market prices fell", ...) have a
  99th percentile of 1.3-2.2 and a maximum of 2.1-2.8 ("a giraffe in the savanna", closest
  to the toy cat, reaches 3.7); object queries on valid-grasp windows have medians 5.2-8.2
  -> 3.0. Grasp-level on the 162 valid grasps, 10 object queries, threshold 3.0: relative
  0 finds 92% of the grasps of the queried object and matches 2.4% of other objects'
  grasps; 0.4 finds 92% / matches 2.2%; 0.6 finds 87% / 0.8%. Occurrence counting must
  not miss grasps, so RELATIVE_KEEP = 0.4 (which still removes the text near miss above).

**Occurrences.** ``count`` / ``last`` / ``first`` work on occurrences: matching items of one
session whose (aligned) spans ``[t, t_end]`` overlap or lie within ``merge_gap`` seconds of
each other merge into one; adjacent windows of one stream (same session + sense + source)
are one occurrence, and a touch window with the note written about it is one too.

**Candidates.** Each sense contributes at most :data:`MATCH_CANDIDATES` candidates (the top of
a prefiltered search): ``count`` over a long session with more matching windows than that is
a lower bound, and :class:`Occurrences` says so (``capped=True``); narrow it with
``after``/``before``.

**Clock offsets.** ``set_clock_offset(session, sense, offset, source)`` records that a stream's
clock runs ``offset`` seconds behind the session's reference clock: its items are placed at
``t + offset`` (``t_aligned``) for grouping, ordering and every ``after``/``before`` bound of
this module. Offsets live in the store's ``meta`` table (persisted, shared by processes).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, Field

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
from tactus_memory.senses import validate_sense_name
from tactus_memory.store import HIT_COLUMNS, Where, finite_float, validate_id, validate_source

#: largest clock offset in seconds (about 317 years): keeps t_aligned = t + offset finite
MAX_CLOCK_OFFSET = 1e10

if TYPE_CHECKING:
    import threading

    from tactus_memory.spaces.base import Space
    from tactus_memory.store import Store

# --------------------------------------------------------------------------- constants
#: per-sense match threshold on the calibrated score (z vs the probe null); see the module
#: docstring and tests/test_temporal_real.py for the measured separation behind each value
MATCH_Z: dict[str, float] = {"text": 3.0, "touch": 3.0}
#: threshold for senses not in MATCH_Z (motion, image, ...)
DEFAULT_MATCH_Z = 3.0
#: a match must also score >= RELATIVE_KEEP x the best score of its sense for the query
RELATIVE_KEEP = 0.4
#: candidates pulled per sense before thresholding (the cap on count over long sessions)
MATCH_CANDIDATES = 500
#: occurrences: matching items within this many seconds of each other are one occurrence
DEFAULT_MERGE_GAP = 2.0
#: moments (search grouping): hits within this many seconds of each other are one moment
DEFAULT_MOMENT_GAP = 1.0
#: moment score = best member score + this bonus per other sense with a *matching* member
CORROBORATION_BONUS = 0.5
#: moments: candidates per sense = max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN) (<= MAX_K)
MOMENT_POOL_FACTOR = 5
MOMENT_POOL_MIN = 50
#: moments: a candidate joins a moment only if it scores above the sense's null mean by this
MOMENT_MIN_Z = 1.0
#: before/after: the default window (seconds)
DEFAULT_WINDOW = 30.0
#: the most rows one timeline (or one before/after window) reads; narrow with after/before
TIMELINE_MAX = 100_000
#: store meta key holding every clock offset as JSON
CLOCK_KEY = "clock_offsets"

Side = Literal["before", "after"]


# --------------------------------------------------------------------------- models
class TimelineItem(BaseModel):
    """One stored item placed on the session clock (``t_aligned = t + clock offset``)."""

    id: str
    session: str
    sense: str
    source: str = ""
    t: float
    t_end: float
    t_aligned: float
    t_end_aligned: float
    text: str | None = None
    meta: dict[str, Any] = Field(default_factory=dict)
    episode: int | None = None


class Evidence(TimelineItem):
    """A scored item: ``score`` is the calibrated z-score, ``match`` whether it clears the
    per-sense threshold and the relative gate for the query."""

    score: float
    cosine: float
    match: bool = False


class Moment(BaseModel):
    """Hits of one session that happen together. ``t``/``t_end`` span the members on the
    aligned clock; ``score`` = best member score + CORROBORATION_BONUS per other sense with a
    matching member; ``hits`` (time order) is every sense's evidence."""

    session: str
    t: float
    t_end: float
    score: float
    senses: list[str]
    best: str
    hits: list[Evidence]


class Occurrences(BaseModel):
    """Distinct occurrences of a query (``count == len(moments)``), in time order."""

    query: str
    count: int
    capped: bool = Field(
        description="True when a sense returned MATCH_CANDIDATES candidates that all matched: "
        "the count is a lower bound (narrow with after/before)."
    )
    merge_gap: float
    moments: list[Moment]


class Context(BaseModel):
    """What happened in ``window`` seconds before/after the anchor (same session)."""

    side: Side
    window: float
    anchor: Evidence
    t_from: float
    t_to: float
    items: list[TimelineItem]


class ClockOffset(BaseModel):
    """A stream's clock offset: its items are placed at ``t + offset`` on the session clock."""

    session: str
    sense: str
    source: str = ""
    offset: float


# --------------------------------------------------------------------------- pure helpers
def resolve_thresholds(
    threshold: float | Mapping[str, float] | None, senses: Sequence[str]
) -> dict[str, float]:
    """Per-sense thresholds: MATCH_Z / DEFAULT_MATCH_Z, overridden by a number (every sense)
    or a mapping (those senses)."""
    out = {s: MATCH_Z.get(s, DEFAULT_MATCH_Z) for s in senses}
    if threshold is None:
        return out
    if isinstance(threshold, Mapping):
        for name, value in threshold.items():
            out[validate_sense_name(name)] = finite_float(value, f"threshold[{name}]")
        return out
    value = finite_float(threshold, "threshold")
    return dict.fromkeys(out, value)


def check_relative(relative: float) -> float:
    value = finite_float(relative, "relative")
    if not 0.0 <= value <= 1.0:
        raise InvalidInputError(f"relative must be in [0, 1], got {relative!r}")
    return value


def check_seconds(value: float, what: str) -> float:
    out = finite_float(value, what)
    if out < 0:
        raise InvalidInputError(f"{what} must be >= 0 seconds, got {value!r}")
    return out


def match_flags(scores: Sequence[float], threshold: float, relative: float) -> list[bool]:
    """Which of one sense's scores match: ``>= threshold`` and ``>= relative * best``."""
    if not scores:
        return []
    bar = max(threshold, relative * max(scores))
    return [s >= bar for s in scores]


def group_moments(
    evidence: Sequence[Evidence], gap: float, *, per_stream: bool = False
) -> list[Moment]:
    """Merge evidence of one session (``per_stream``: of one session + sense + source) whose
    aligned spans overlap or lie within ``gap`` seconds (transitively) into moments; returns
    them in time order (t, t_end, session)."""
    by_key: dict[tuple[str, ...], list[Evidence]] = {}
    for e in evidence:
        key = (e.session, e.sense, e.source) if per_stream else (e.session,)
        by_key.setdefault(key, []).append(e)
    out: list[Moment] = []
    for key in sorted(by_key):
        items = sorted(
            by_key[key],
            key=lambda e: (e.t_aligned, e.t_end_aligned, e.sense, e.source, e.id),
        )
        group: list[Evidence] = []
        end = -math.inf
        for e in items:
            if group and e.t_aligned > end + gap:
                out.append(make_moment(group))
                group = []
            group.append(e)
            end = max(end, e.t_end_aligned) if len(group) > 1 else e.t_end_aligned
        if group:
            out.append(make_moment(group))
    out.sort(key=lambda m: (m.t, m.t_end, m.session))
    return out


def make_moment(hits: Sequence[Evidence]) -> Moment:
    """One moment from its members (see :class:`Moment` for the score)."""
    best = min(hits, key=lambda e: (-e.score, e.t_aligned, e.id))  # ties: the earliest
    corroborating = {e.sense for e in hits if e.match and e.sense != best.sense}
    return Moment(
        session=best.session,
        t=min(e.t_aligned for e in hits),
        t_end=max(e.t_end_aligned for e in hits),
        score=best.score + CORROBORATION_BONUS * len(corroborating),
        senses=sorted({e.sense for e in hits}),
        best=best.id,
        hits=list(hits),
    )


def _row_item(row: dict[str, Any], offset: float) -> dict[str, Any]:
    return {
        "id": row["id"],
        "session": row["session"],
        "sense": row["sense"],
        "source": row.get("source") or "",
        "t": row["t"],
        "t_end": row["t_end"],
        "t_aligned": row["t"] + offset,
        "t_end_aligned": row["t_end"] + offset,
        "text": row.get("text"),
        "meta": json.loads(row["meta"] or "{}") if isinstance(row.get("meta"), str) else {},
        "episode": row.get("episode"),
    }


def _overlaps(item: TimelineItem, after: float | None, before: float | None) -> bool:
    return (after is None or item.t_end_aligned >= after) and (
        before is None or item.t_aligned <= before
    )


# --------------------------------------------------------------------------- mixin
class TemporalMixin:
    """Temporal operators, moments, episodes and clock offsets; ``Memory`` inherits it.

    Every operation takes the usual filters: ``session``, ``senses`` (default: every sense
    with rows), ``source`` and ``after``/``before`` (overlap semantics, on the aligned clock).
    """

    # provided by Memory
    store: Store
    space: Space
    _lock: threading.RLock

    # ----------------------------------------------------------- clock offsets
    def _offset_table(self) -> dict[str, dict[str, float]]:
        raw = self.store.get_meta(CLOCK_KEY)
        return json.loads(raw) if raw else {}

    def _offsets(self) -> dict[tuple[str, str, str], float]:
        return {
            (session, *key.split("/", 1)): float(v)  # type: ignore[misc]
            for session, streams in self._offset_table().items()
            for key, v in streams.items()
        }

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock.

        Persisted in the store; ``offset=0`` removes the entry. The sense need not exist yet.
        """
        session = validate_id(session, "session id")
        sense = validate_sense_name(sense)
        source = validate_source(source)
        value = finite_float(offset, "offset")
        if abs(value) > MAX_CLOCK_OFFSET:
            raise InvalidInputError(
                f"offset {value!r} is beyond +-{MAX_CLOCK_OFFSET:g} s; a clock offset is a "
                "time shift, and t + offset must stay a finite number"
            )
        with self._lock:
            table = self._offset_table()
            streams = table.setdefault(session, {})
            key = f"{sense}/{source}"
            if value == 0.0:
                streams.pop(key, None)
                if not streams:
                    table.pop(session)
            else:
                streams[key] = value
            self.store.set_meta(CLOCK_KEY, json.dumps(table, sort_keys=True))

    def clock_offsets(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        if session is not None:
            validate_id(session, "session id")
        return [
            ClockOffset(session=s, sense=sense, source=source, offset=v)
            for (s, sense, source), v in sorted(self._offsets().items())
            if session is None or s == session
        ]

    def _pad(self, offsets: Mapping[tuple[str, str, str], float], session: str | None) -> float:
        """How far store-side time bounds must be widened so no aligned item is missed."""
        vals = [abs(v) for (s, _, _), v in offsets.items() if session is None or s == session]
        return max(vals, default=0.0)

    def _where(
        self,
        offsets: Mapping[tuple[str, str, str], float],
        *,
        session: str | None,
        after: float | None,
        before: float | None,
        source: str | None,
    ) -> Where:
        after = None if after is None else finite_float(after, "after")
        before = None if before is None else finite_float(before, "before")
        if after is not None and before is not None and after > before:
            raise InvalidInputError(f"after ({after}) is later than before ({before})")
        pad = self._pad(offsets, session)
        return (
            Where()
            .session(session)
            .overlaps(
                None if after is None else after - pad, None if before is None else before + pad
            )
            .source(source)
        )

    # ----------------------------------------------------------- scoring
    def _embed_query(self, query: str) -> np.ndarray:
        from tactus_memory.memory import _check_query_text
        from tactus_memory.vectors import as_unit_rows

        query = _check_query_text(query)
        return as_unit_rows(self.space.embed_texts([query], query=True), self.space.dim)

    def _evidence(
        self,
        query: str,
        *,
        senses: Sequence[str] | None,
        session: str | None,
        after: float | None,
        before: float | None,
        source: str | None,
        threshold: float | Mapping[str, float] | None,
        relative: float,
        per_sense: int,
    ) -> tuple[list[Evidence], bool]:
        """Every candidate (all senses), scored and flagged; and whether a sense was capped."""
        relative = check_relative(relative)
        offsets = self._offsets()
        base = self._where(offsets, session=session, after=after, before=before, source=source)
        names = self._senses_to_search(senses)  # type: ignore[attr-defined]
        bars = resolve_thresholds(threshold, names)
        q = self._embed_query(query)
        out: list[Evidence] = []
        capped = False
        for name in names:
            hits = self._query(q, per_sense, [name], base, transform=True)  # type: ignore[attr-defined]
            flags = match_flags([h.score for h in hits], bars[name], relative)
            capped = capped or (len(hits) >= per_sense and all(flags))
            for h, flag in zip(hits, flags, strict=True):
                off = offsets.get((h.session, h.sense, h.source), 0.0)
                e = Evidence(
                    **h.model_dump(exclude={"score", "cosine"}),
                    t_aligned=h.t + off,
                    t_end_aligned=h.t_end + off,
                    score=h.score,
                    cosine=h.cosine,
                    match=flag,
                )
                if _overlaps(e, after, before):
                    out.append(e)
        return out, capped

    def matches(
        self,
        query: str,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
    ) -> list[Evidence]:
        """Every item matching ``query`` (see the module docstring), in aligned time order."""
        ev, _ = self._evidence(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            per_sense=MATCH_CANDIDATES,
        )
        return sorted((e for e in ev if e.match), key=lambda e: (e.t_aligned, e.sense, e.id))

    # ----------------------------------------------------------- last / first / count
    def occurrences(
        self,
        query: str,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
    ) -> Occurrences:
        """Distinct occurrences of ``query``: matching items merged per session when their
        aligned spans overlap or lie within ``merge_gap`` seconds. ``per_stream=True`` merges
        only within one stream (session + sense + source): a grasp and its note count twice."""
        gap = check_seconds(merge_gap, "merge_gap")
        ev, capped = self._evidence(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            per_sense=MATCH_CANDIDATES,
        )
        moments = group_moments([e for e in ev if e.match], gap, per_stream=per_stream)
        return Occurrences(
            query=query, count=len(moments), capped=capped, merge_gap=gap, moments=moments
        )

    def count(
        self,
        query: str,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
    ) -> int:
        """How many distinct times ``query`` happened (see :meth:`occurrences`)."""
        return self.occurrences(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            merge_gap=merge_gap,
            per_stream=per_stream,
        ).count

    def last(
        self,
        query: str,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
        merge_gap: float = DEFAULT_MERGE_GAP,
    ) -> Moment | None:
        """The most recent occurrence of ``query`` (latest aligned start), or None."""
        occ = self.occurrences(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            merge_gap=merge_gap,
        )
        return occ.moments[-1] if occ.moments else None

    def first(
        self,
        query: str,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
        merge_gap: float = DEFAULT_MERGE_GAP,
    ) -> Moment | None:
        """The earliest occurrence of ``query`` (earliest aligned start), or None."""
        occ = self.occurrences(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            merge_gap=merge_gap,
        )
        return occ.moments[0] if occ.moments else None

    # ----------------------------------------------------------- before / after
    def before(
        self,
        anchor: str,
        window: float = DEFAULT_WINDOW,
        *,
        senses: Sequence[str] | None = None,
        anchor_senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``: items of
        the anchor's session (of ``senses``) that start in ``[a.t - window, a.t)`` (aligned).
        ``session``/``after``/``before``/``anchor_senses`` restrict where the anchor is
        searched. None when nothing matches the anchor."""
        return self._around(
            "before", anchor, window, senses, anchor_senses, session, after, before, source,
            threshold, relative,
        )  # fmt: skip

    def after(
        self,
        anchor: str,
        window: float = DEFAULT_WINDOW,
        *,
        senses: Sequence[str] | None = None,
        anchor_senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
    ) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor``: items of
        the anchor's session (of ``senses``) that start in ``[a.t_end, a.t_end + window]``
        (aligned), the anchor itself excluded. None when nothing matches the anchor."""
        return self._around(
            "after", anchor, window, senses, anchor_senses, session, after, before, source,
            threshold, relative,
        )  # fmt: skip

    def _around(
        self,
        side: Side,
        anchor: str,
        window: float,
        senses: Sequence[str] | None,
        anchor_senses: Sequence[str] | None,
        session: str | None,
        after: float | None,
        before: float | None,
        source: str | None,
        threshold: float | Mapping[str, float] | None,
        relative: float,
    ) -> Context | None:
        window = check_seconds(window, "window")
        names = None if senses is None else self._senses_to_search(senses)  # type: ignore[attr-defined]
        found = self.matches(
            anchor,
            senses=anchor_senses,
            session=session,
            after=after,
            before=before,
            threshold=threshold,
            relative=relative,
        )
        if not found:
            return None
        a = max(found, key=lambda e: (e.score, e.t_aligned, e.id))
        if side == "before":
            lo, hi = a.t_aligned - window, a.t_aligned
        else:
            lo, hi = a.t_end_aligned, a.t_end_aligned + window
        offsets = self._offsets()
        pad = self._pad(offsets, a.session)
        where = Where().session(a.session).t_range(lo - pad, None).source(source)
        where.parts.append(f"t <= {float(hi + pad)!r}")
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
    def _items(
        self, where: Where, offsets: Mapping[tuple[str, str, str], float]
    ) -> list[TimelineItem]:
        rows = self.store.scan(where.sql(), HIT_COLUMNS, limit=TIMELINE_MAX + 1).to_pylist()
        if len(rows) > TIMELINE_MAX:
            raise InvalidInputError(
                f"more than {TIMELINE_MAX} items in range; narrow it with after/before or senses"
            )
        items = [
            TimelineItem(
                **_row_item(r, offsets.get((r["session"], r["sense"], r.get("source") or ""), 0.0))
            )
            for r in rows
        ]
        items.sort(key=lambda it: (it.t_aligned, it.t_end_aligned, it.sense, it.source, it.id))
        return items

    def timeline(
        self,
        session: str,
        senses: Sequence[str] | None = None,
        after: float | None = None,
        before: float | None = None,
        episodes: bool = False,
        *,
        source: str | None = None,
        limit: int | None = None,
    ) -> list[TimelineItem] | list[Episode]:
        """The session's items (or, with ``episodes=True``, its episodes) in aligned time order.

        ``after``/``before`` use overlap semantics on the aligned clock; ``limit`` keeps the
        first items. Episodes: the session is segmented first if any of its items has no
        episode id yet (see :meth:`segment_episodes`). Raises NotFoundError for an unknown
        session.
        """
        session = validate_id(session, "session id")
        if limit is not None and (
            isinstance(limit, bool) or not isinstance(limit, int) or limit < 1
        ):
            raise InvalidInputError(f"limit must be a positive int, got {limit!r}")
        names = None if senses is None else self._senses_to_search(senses)  # type: ignore[attr-defined]
        offsets = self._offsets()
        if self.store.count(Where().session(session).sql()) == 0:
            raise NotFoundError(f"no session {session!r}")
        if episodes:
            eps = self.episodes(session, senses=names, source=source)
            eps = [
                e
                for e in eps
                if (after is None or e.t_end_aligned >= after)
                and (before is None or e.t_aligned <= before)
            ]
            return eps[:limit] if limit else eps
        where = self._where(offsets, session=session, after=after, before=before, source=source)
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
        import pyarrow as pa

        check_rule(min_cos, mean_cos, max_gap)
        if session is None:
            sessions = [s.id for s in self.sessions()]  # type: ignore[attr-defined]
        else:
            sessions = [validate_id(session, "session id")]
        total = 0
        for sid in sessions:
            cols = ["id", "sense", "source", "t", "t_end", "vector"]
            tbl = self.store.scan(Where().session(sid).sql(), cols)
            if tbl.num_rows == 0:
                if session is not None:
                    raise NotFoundError(f"no session {sid!r}")
                continue
            ids = tbl.column("id").to_pylist()
            streams = _streams(tbl)
            firsts: list[tuple[float, str, str, int, np.ndarray]] = []
            vecs = _vectors(tbl, self.space.dim)
            t = tbl.column("t").to_numpy()
            t_end = tbl.column("t_end").to_numpy()
            for (sense, source), idx in sorted(streams.items()):
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
            data = pa.table({"id": ids, "episode": pa.array(episode, pa.int64())})
            with self._lock:
                (
                    self.store.items.merge_insert("id")
                    .when_matched_update_all()
                    .execute(data)
                )  # fmt: skip
            total += len(firsts)
        return total

    def episodes(
        self,
        session: str,
        *,
        senses: Sequence[str] | None = None,
        source: str | None = None,
    ) -> list[Episode]:
        """The session's episodes in aligned time order (segmenting it first if needed)."""
        session = validate_id(session, "session id")
        where = Where().session(session)
        if self.store.count(where.sql()) == 0:
            raise NotFoundError(f"no session {session!r}")
        unsegmented = Where().session(session)
        unsegmented.parts.append("episode IS NULL")
        if self.store.count(unsegmented.sql()) > 0:
            self.segment_episodes(session)
        names = None if senses is None else self._senses_to_search(senses)  # type: ignore[attr-defined]
        if names is not None:
            where.senses(names)
        where.source(source)
        cols = ["id", "sense", "source", "t", "t_end", "episode", "vector"]
        tbl = self.store.scan(where.sql(), cols)
        offsets = self._offsets()
        if tbl.num_rows == 0:
            return []
        vecs = _vectors(tbl, self.space.dim)
        ids = tbl.column("id").to_pylist()
        senses_col = tbl.column("sense").to_pylist()
        sources = [s or "" for s in tbl.column("source").to_pylist()]
        t = tbl.column("t").to_numpy()
        t_end = tbl.column("t_end").to_numpy()
        ep = tbl.column("episode").to_numpy()
        out = []
        for number in np.unique(ep):
            members = np.flatnonzero(ep == number)
            members = members[np.lexsort((np.array(ids, dtype=object)[members], t[members]))]
            first = members[0]
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
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        gap: float = DEFAULT_MOMENT_GAP,
        threshold: float | Mapping[str, float] | None = None,
        relative: float = RELATIVE_KEEP,
    ) -> list[Moment]:
        """Search, then group hits of one session whose aligned spans overlap or lie within
        ``gap`` seconds into moments carrying every sense's evidence; best ``k`` moments.

        Candidates: the top max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN) per sense that score
        at least MOMENT_MIN_Z (above the sense's null mean). Score: see :class:`Moment`.
        """
        from tactus_memory.memory import MAX_K, _check_k

        k = _check_k(k)
        gap = check_seconds(gap, "gap")
        pool = min(MAX_K, max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN))
        ev, _ = self._evidence(
            query,
            senses=senses,
            session=session,
            after=after,
            before=before,
            source=source,
            threshold=threshold,
            relative=relative,
            per_sense=pool,
        )
        moments = group_moments([e for e in ev if e.match or e.score >= MOMENT_MIN_Z], gap)
        moments.sort(key=lambda m: (-m.score, m.t, m.session))
        return moments[:k]

    def search_grouped(
        self, query: str, k: int = 10, *, group: str, gap: float | None = None, **filters: Any
    ) -> list[Moment]:
        """``Memory.search(..., group="moment", gap=...)`` lands here."""
        if group != "moment":
            raise InvalidInputError(f"unknown group {group!r}; use group='moment'")
        return self.search_moments(
            query, k, gap=DEFAULT_MOMENT_GAP if gap is None else gap, **filters
        )


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


def _vectors(tbl: Any, dim: int) -> np.ndarray:
    flat = tbl.column("vector").combine_chunks().flatten()
    return np.asarray(flat, dtype=np.float32).reshape(-1, dim)
