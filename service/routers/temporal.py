"""Temporal questions: last / first / count / before / after, moments, timelines, episodes and
per-stream clock offsets (``tactus_memory.temporal.operators``).

"A match" is a calibrated score over a per-sense threshold and close to the best of its sense
(see ``tactus_memory.matching``); ``threshold`` here sets one bar for every sense searched.
Every route takes the one scope dependency (``deps.ScopeDep``) and the match bar
(``MatchDep``), and hands both to the library as they are.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query

from tactus_memory.limits import MAX_K, MAX_TEXT_CHARS, SENSE_NAME_PATTERN
from tactus_memory.matching import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    RELATIVE_KEEP,
    Match,
)
from tactus_memory.results import Occurrences, Side
from tactus_memory.search.grasps import OCCURRENCE_POOL
from tactus_memory.service.deps import (
    GraspPool,
    MemoryDep,
    QueryText,
    Read,
    ScopeDep,
    SessionId,
    SortQ,
    StreamScopeDep,
    Write,
)
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.temporal_schemas import (
    ClockIn,
    ClockOut,
    ContextOut,
    MomentOut,
    MomentsOut,
    SegmentIn,
    SegmentOut,
    TimelineOut,
)

ERRORS = problem_responses(404, 422)
#: every temporal route answers 404 (unknown session/sense) and 422 (bad input) problems
router = APIRouter(tags=["temporal"], responses=ERRORS)

Threshold = Annotated[
    float | None,
    Query(description="Match bar on the calibrated score for every sense (default per sense)."),
]
Relative = Annotated[
    float, Query(ge=0.0, le=1.0, description="A match must score >= relative x its sense's best.")
]
MergeGap = Annotated[
    float, Query(ge=0.0, le=1e9, description="Matches this close (s) are one occurrence.")
]
GroupGrasp = Annotated[
    Literal["auto", "window", "grasp"],
    Query(
        description="`auto` (default): touch is asked of grasps (a touch stream's contiguous "
        "windows, pooled), other senses of items; `window`: of items everywhere; `grasp`: of "
        "grasps for every sense."
    ),
]


Answer = Annotated[
    float | None,
    Query(
        ge=0.0,
        le=1.0,
        description="last/first/count answer from the occurrences above the first step down "
        "to less than answer x the score above it, per sense (default: 0.75 for text, 0 for "
        "the others; 0: every occurrence past the bar).",
    ),
]


def match_bar(
    threshold: Threshold = None, relative: Relative = RELATIVE_KEEP, answer: Answer = None
) -> Match:
    """The match bar's query parameters -> :class:`~tactus_memory.matching.Match`."""
    return Match(threshold=threshold, relative=relative, answer=answer)


MatchDep = Annotated[Match, Depends(match_bar)]


@dataclass
class Asked:
    """What every temporal question is asked with: the memory, the scope, the match bar."""

    memory: MemoryDep
    scope: ScopeDep
    match: MatchDep


AskedDep = Annotated[Asked, Depends()]


@dataclass
class Occurrence:
    """An occurrence question (/last, /first, /count) as one dependency."""

    asked: AskedDep
    q: QueryText
    merge_gap: MergeGap = DEFAULT_MERGE_GAP
    group: GroupGrasp = "auto"
    pool: GraspPool = OCCURRENCE_POOL
    sort: SortQ = None

    def ask(self, per_stream: bool = False) -> Occurrences:
        a = self.asked
        if a.scope.session is not None:
            a.memory.session(a.scope.session)  # an unknown session: 404, as /timeline says
        return a.memory.occurrences(
            self.q,
            scope=a.scope,
            match=a.match,
            merge_gap=self.merge_gap,
            per_stream=per_stream,
            group=self.group,
            pool=self.pool,
            sort=self.sort,
        )


OccurrenceDep = Annotated[Occurrence, Depends()]


@router.get(
    "/last",
    dependencies=[Read],
    summary="The most recent occurrence of something",
    description="Matching items (per-sense calibrated threshold), merged into occurrences; the "
    "one that started last (with `sort`: the last in that order). `moment` is null when "
    "nothing matches; an unknown `session` is a 404.",
    response_model=MomentOut,
)
def last(question: OccurrenceDep) -> MomentOut:
    moments = question.ask().moments
    return MomentOut(moment=moments[-1] if moments else None)


@router.get(
    "/first",
    dependencies=[Read],
    summary="The earliest occurrence of something",
    description="As /last, the one that started first (with `sort`: the first in that "
    "order, e.g. `sort=-force`: the firmest).",
    response_model=MomentOut,
)
def first(question: OccurrenceDep) -> MomentOut:
    moments = question.ask().moments
    return MomentOut(moment=moments[0] if moments else None)


@router.get(
    "/count",
    dependencies=[Read],
    summary="How many distinct times something happened",
    description="Matching items within `merge_gap` seconds of each other (same session) are "
    "one occurrence. `capped` is true when the count is a lower bound.",
    response_model=Occurrences,
)
def count(
    question: OccurrenceDep,
    per_stream: Annotated[
        bool, Query(description="Merge only within one stream (session + sense + source).")
    ] = False,
) -> Occurrences:
    return question.ask(per_stream)


Anchor = Annotated[
    str,
    Query(min_length=1, max_length=MAX_TEXT_CHARS, description="What the window is relative to."),
]
Window = Annotated[float, Query(ge=0.0, le=1e9, description="Seconds before/after the anchor.")]
AnchorSenses = Annotated[
    list[str] | None,
    Query(
        description="Search the anchor in these senses (repeat).",
        json_schema_extra={"items": {"type": "string", "pattern": SENSE_NAME_PATTERN}},
    ),
]


@dataclass
class Around:
    """A /before or /after question as one dependency."""

    asked: AskedDep
    anchor: Anchor
    window: Window = DEFAULT_WINDOW
    anchor_sense: AnchorSenses = None

    def ask(self, side: Side) -> ContextOut:
        a = self.asked
        around = a.memory.before if side == "before" else a.memory.after
        ctx = around(
            self.anchor, self.window, scope=a.scope, match=a.match, anchor_senses=self.anchor_sense
        )
        if ctx is None:
            return ContextOut(side=side, window=self.window)
        return ContextOut.model_validate(ctx.model_dump())


AroundDep = Annotated[Around, Depends()]


def _around_route(side: Side) -> Callable[[Around], ContextOut]:
    def route(question: AroundDep) -> ContextOut:
        return question.ask(side)

    route.__name__ = side  # the operation id: `before` / `after` (app.operation_id)
    return route


#: /before and /after: one route each, the same parameters, the window on either side
AROUND_ROUTES = {
    "before": "starts in the `window` seconds before it (aligned clock).",
    "after": "starts in the `window` seconds after it ends (aligned clock).",
}
for _side, _window_doc in AROUND_ROUTES.items():
    router.get(
        f"/{_side}",
        dependencies=[Read],
        summary=f"What happened {_side} something",
        description="The best match of `anchor`, then every item of its session (of `sense`) "
        "that " + _window_doc,
        response_model=ContextOut,
    )(_around_route(_side))


@router.get(
    "/moments",
    dependencies=[Read],
    summary="Search, grouped into moments (every sense's evidence together)",
    description="Hits of one session whose spans overlap or lie within `gap` seconds (aligned "
    "clocks) form one moment; score = best member + a bonus per other matching sense. The "
    "same as `memory.search(q, group='moment')`.",
    response_model=MomentsOut,
)
def moments(
    memory: MemoryDep,
    q: QueryText,
    scope: ScopeDep,
    match: MatchDep,
    k: Annotated[int, Query(ge=1, le=MAX_K, description="How many moments.")] = 10,
    gap: Annotated[float, Query(ge=0.0, le=1e9)] = DEFAULT_MOMENT_GAP,
    group: GroupGrasp = "auto",
    pool: GraspPool = "mean",
    sort: SortQ = None,
) -> MomentsOut:
    moments = memory.search_moments(
        q, k, gap=gap, group=group, pool=pool, sort=sort, scope=scope, match=match
    )
    return MomentsOut(moments=moments)


@router.get(
    "/sessions/{session}/timeline",
    dependencies=[Read],
    summary="A session in time order: items, or episodes",
    description="Items (or, with `episodes=true`, episodes: stretches of one stream whose "
    "embeddings stay coherent) in aligned time order. Times filter by overlap. A read: "
    "episodes not yet stored are computed for the answer and not written (store them with "
    "`POST /sessions/{session}/episodes`).",
    response_model=TimelineOut,
)
def timeline(
    session: SessionId,
    memory: MemoryDep,
    scope: StreamScopeDep,
    episodes: bool = False,
    limit: Annotated[int | None, Query(ge=1, le=100_000)] = None,
) -> TimelineOut:
    out = memory.timeline(session, **scope.keywords(), episodes=episodes, limit=limit)
    if episodes:
        return TimelineOut(session=session, episodes=out)
    return TimelineOut(session=session, items=out)


@router.post(
    "/sessions/{session}/episodes",
    dependencies=[Write],
    summary="Segment a session's streams into episodes (stored)",
    response_model=SegmentOut,
)
def segment_episodes(
    session: SessionId, memory: MemoryDep, body: SegmentIn | None = None
) -> SegmentOut:
    body = body or SegmentIn()
    n = memory.segment_episodes(
        session, min_cos=body.min_cos, mean_cos=body.mean_cos, max_gap=body.max_gap
    )
    return SegmentOut(session=session, episodes=n)


@router.get(
    "/sessions/{session}/clock",
    dependencies=[Read],
    summary="The session's clock offsets",
    response_model=ClockOut,
)
def get_clock(session: SessionId, memory: MemoryDep) -> ClockOut:
    offsets = memory.clock_offsets(session)
    if not offsets:
        memory.session(session)  # 404 for a session that has neither items nor offsets
    return ClockOut(offsets=offsets)


@router.put(
    "/sessions/{session}/clock",
    dependencies=[Write],
    summary="Set a stream's clock offset (t_aligned = t + offset)",
    response_model=ClockOut,
)
def set_clock(session: SessionId, body: ClockIn, memory: MemoryDep) -> ClockOut:
    memory.set_clock_offset(session, body.sense, body.offset, source=body.source)
    return ClockOut(offsets=memory.clock_offsets(session))
