"""Temporal questions: last / first / count / before / after, moments, timelines, episodes and
per-stream clock offsets (``tactus_memory.temporal``).

"A match" is a calibrated score over a per-sense threshold and close to the best of its sense
(see the library docstring); ``threshold`` here sets one bar for every sense searched.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query
from pydantic import BaseModel, ConfigDict, Field

from tactus_memory.episodes import EPISODE_MAX_GAP, EPISODE_MEAN_COS, EPISODE_MIN_COS, Episode
from tactus_memory.service.deps import ID_PATTERN, MemoryDep, SessionId
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SENSE_PATTERN, SOURCE_PATTERN, Strict
from tactus_memory.temporal import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    MAX_CLOCK_OFFSET,
    RELATIVE_KEEP,
    ClockOffset,
    Evidence,
    Moment,
    Occurrences,
    TimelineItem,
)

router = APIRouter(tags=["temporal"])

K_MAX = 1000
ERRORS = problem_responses(404, 422)

Query_ = Annotated[str, Query(min_length=1, max_length=8192, description="The query in words.")]
Senses = Annotated[
    list[str] | None,
    Query(
        description="Restrict to these senses (repeat the parameter).",
        json_schema_extra={"items": {"type": "string", "pattern": SENSE_PATTERN}},
    ),
]
SessionQ = Annotated[str | None, Query(pattern=ID_PATTERN, max_length=128)]
SourceQ = Annotated[
    str | None,
    Query(
        max_length=128,
        pattern=SOURCE_PATTERN,
        description="Only this stream (source id; '' for none).",
    ),
]
After = Annotated[
    float | None,
    Query(description="Items still going on at or after (aligned); must be <= before (422)."),
]
Before = Annotated[
    float | None,
    Query(description="Items started at or before (aligned); must be >= after (422)."),
]
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


class MomentOut(BaseModel):
    """The occurrence found, or null when nothing matches."""

    moment: Moment | None


class MomentsOut(BaseModel):
    moments: list[Moment]


class ContextOut(BaseModel):
    """What happened before/after the anchor; ``anchor`` null when nothing matches it."""

    side: str
    window: float
    anchor: Evidence | None = None
    t_from: float | None = None
    t_to: float | None = None
    items: list[TimelineItem] = Field(default_factory=list)


class TimelineOut(BaseModel):
    session: str
    items: list[TimelineItem] | None = None
    episodes: list[Episode] | None = None


class ClockIn(Strict):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"sense": "touch", "source": "glove-l", "offset": 2.5}]},
    )

    sense: str = Field(pattern=SENSE_PATTERN)
    source: str = Field(
        "", max_length=128, pattern=SOURCE_PATTERN, description="Stream id ('' for none)."
    )
    offset: float = Field(
        ge=-MAX_CLOCK_OFFSET,
        le=MAX_CLOCK_OFFSET,
        description="Seconds added to the stream's t to put it on the session clock (0 clears).",
    )


class ClockOut(BaseModel):
    offsets: list[ClockOffset]


class SegmentIn(Strict):
    min_cos: float = Field(EPISODE_MIN_COS, ge=-1.0, le=1.0)
    mean_cos: float = Field(EPISODE_MEAN_COS, ge=-1.0, le=1.0)
    max_gap: float = Field(EPISODE_MAX_GAP, ge=0.0)


class SegmentOut(BaseModel):
    session: str
    episodes: int = Field(description="Episodes written.")


class MatchFilters:
    """The query parameters every temporal question shares (one dependency, one place)."""

    def __init__(
        self,
        sense: Senses = None,
        session: SessionQ = None,
        source: SourceQ = None,
        after: After = None,
        before: Before = None,
        threshold: Threshold = None,
        relative: Relative = RELATIVE_KEEP,
    ) -> None:
        self.scope = {
            "senses": sense,
            "session": session,
            "source": source,
            "after": after,
            "before": before,
        }
        self.match = {"threshold": threshold, "relative": relative}

    def kw(self) -> dict[str, Any]:
        """Keyword arguments for the library call: scope filters and the match bar."""
        return {**self.scope, **self.match}


Filters = Annotated[MatchFilters, Depends()]


@router.get(
    "/last",
    summary="The most recent occurrence of something",
    description="Matching items (per-sense calibrated threshold), merged into occurrences; the "
    "one that started last. `moment` is null when nothing matches.",
    response_model=MomentOut,
    responses=ERRORS,
)
def last(
    memory: MemoryDep, q: Query_, f: Filters, merge_gap: MergeGap = DEFAULT_MERGE_GAP
) -> MomentOut:
    return MomentOut(moment=memory.last(q, merge_gap=merge_gap, **f.kw()))


@router.get(
    "/first",
    summary="The earliest occurrence of something",
    response_model=MomentOut,
    responses=ERRORS,
)
def first(
    memory: MemoryDep, q: Query_, f: Filters, merge_gap: MergeGap = DEFAULT_MERGE_GAP
) -> MomentOut:
    return MomentOut(moment=memory.first(q, merge_gap=merge_gap, **f.kw()))


@router.get(
    "/count",
    summary="How many distinct times something happened",
    description="Matching items within `merge_gap` seconds of each other (same session) are "
    "one occurrence. `capped` is true when the count is a lower bound.",
    response_model=Occurrences,
    responses=ERRORS,
)
def count(
    memory: MemoryDep,
    q: Query_,
    f: Filters,
    merge_gap: MergeGap = DEFAULT_MERGE_GAP,
    per_stream: Annotated[
        bool, Query(description="Merge only within one stream (session + sense + source).")
    ] = False,
) -> Occurrences:
    return memory.occurrences(q, merge_gap=merge_gap, per_stream=per_stream, **f.kw())


def _context(side: str, window: float, ctx: Any) -> ContextOut:
    if ctx is None:
        return ContextOut(side=side, window=window)
    return ContextOut.model_validate(ctx.model_dump())


Anchor = Annotated[
    str, Query(min_length=1, max_length=8192, description="What the window is relative to.")
]
Window = Annotated[float, Query(ge=0.0, le=1e9, description="Seconds before/after the anchor.")]
AnchorSenses = Annotated[
    list[str] | None,
    Query(
        description="Search the anchor in these senses (repeat).",
        json_schema_extra={"items": {"type": "string", "pattern": SENSE_PATTERN}},
    ),
]


@router.get(
    "/before",
    summary="What happened before something",
    description="The best match of `anchor`, then every item of its session (of `sense`) that "
    "starts in the `window` seconds before it (aligned clock).",
    response_model=ContextOut,
    responses=ERRORS,
)
def before_anchor(
    memory: MemoryDep,
    anchor: Anchor,
    f: Filters,
    window: Window = DEFAULT_WINDOW,
    anchor_sense: AnchorSenses = None,
) -> ContextOut:
    ctx = memory.before(anchor, window, anchor_senses=anchor_sense, **f.kw())
    return _context("before", window, ctx)


@router.get(
    "/after",
    summary="What happened after something",
    description="The best match of `anchor`, then every item of its session (of `sense`) that "
    "starts in the `window` seconds after it ends (aligned clock).",
    response_model=ContextOut,
    responses=ERRORS,
)
def after_anchor(
    memory: MemoryDep,
    anchor: Anchor,
    f: Filters,
    window: Window = DEFAULT_WINDOW,
    anchor_sense: AnchorSenses = None,
) -> ContextOut:
    ctx = memory.after(anchor, window, anchor_senses=anchor_sense, **f.kw())
    return _context("after", window, ctx)


@router.get(
    "/moments",
    summary="Search, grouped into moments (every sense's evidence together)",
    description="Hits of one session whose spans overlap or lie within `gap` seconds (aligned "
    "clocks) form one moment; score = best member + a bonus per other matching sense. The "
    "same as `memory.search(q, group='moment')`.",
    response_model=MomentsOut,
    responses=ERRORS,
)
def moments(
    memory: MemoryDep,
    q: Query_,
    f: Filters,
    k: Annotated[int, Query(ge=1, le=K_MAX, description="How many moments.")] = 10,
    gap: Annotated[float, Query(ge=0.0, le=1e9)] = DEFAULT_MOMENT_GAP,
) -> MomentsOut:
    return MomentsOut(moments=memory.search_moments(q, k, gap=gap, **f.kw()))


@router.get(
    "/sessions/{session}/timeline",
    summary="A session in time order: items, or episodes",
    description="Items (or, with `episodes=true`, episodes: stretches of one stream whose "
    "embeddings stay coherent) in aligned time order. Times filter by overlap.",
    response_model=TimelineOut,
    responses=ERRORS,
)
def timeline(
    session: SessionId,
    memory: MemoryDep,
    sense: Senses = None,
    source: SourceQ = None,
    after: After = None,
    before: Before = None,
    episodes: bool = False,
    limit: Annotated[int | None, Query(ge=1, le=100_000)] = None,
) -> TimelineOut:
    out = memory.timeline(
        session, sense, after, before, episodes, source=source, limit=limit
    )  # fmt: skip
    if episodes:
        return TimelineOut(session=session, episodes=out)
    return TimelineOut(session=session, items=out)


@router.post(
    "/sessions/{session}/episodes",
    summary="Segment a session's streams into episodes (stored)",
    response_model=SegmentOut,
    responses=ERRORS,
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
    summary="The session's clock offsets",
    response_model=ClockOut,
    responses=ERRORS,
)
def get_clock(session: SessionId, memory: MemoryDep) -> ClockOut:
    offsets = memory.clock_offsets(session)
    if not offsets:
        memory.session(session)  # 404 for a session that has neither items nor offsets
    return ClockOut(offsets=offsets)


@router.put(
    "/sessions/{session}/clock",
    summary="Set a stream's clock offset (t_aligned = t + offset)",
    response_model=ClockOut,
    responses=ERRORS,
)
def put_clock(session: SessionId, body: ClockIn, memory: MemoryDep) -> ClockOut:
    memory.set_clock_offset(session, body.sense, body.offset, source=body.source)
    return ClockOut(offsets=memory.clock_offsets(session))
