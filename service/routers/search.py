"""Search: natural language (GET /search) and by example (POST /search/like)."""

from __future__ import annotations

import time
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from tactus_memory.limits import MAX_K
from tactus_memory.query import Scope
from tactus_memory.results import Moment
from tactus_memory.senses.windowed import WindowedSense
from tactus_memory.service.arrays import as_window_array
from tactus_memory.service.deps import GraspPool, MemoryDep, QueryText, Read, ScopeDep, SortQ
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import STATED_FRAME, HitOut, SearchLikeIn, SearchOut
from tactus_memory.service.touch_senses import frame_shape

router = APIRouter(prefix="/search", tags=["search"])


def _timing(response: Response, t0: float) -> None:
    """``Server-Timing: library;dur=<ms>``: the time spent in the library call (embedding
    and search), so a client can tell the service's own overhead from the library's work."""
    response.headers["Server-Timing"] = f"library;dur={(time.perf_counter() - t0) * 1e3:.3f}"


def _out(hits: list) -> SearchOut:
    return SearchOut(hits=[HitOut.model_validate(h, from_attributes=True) for h in hits])


@router.get(
    "",
    dependencies=[Read],
    summary="Search every sense in natural language",
    description=(
        "Embeds `q` once in the memory's space and searches the chosen senses (default: every "
        "sense with rows), touch included: *'something soft and squishy'* finds touch windows. "
        "Scores are calibrated per sense so senses merge fairly. Time filters use overlap: an "
        "item spanning [t, t_end] matches when t_end >= after and t <= before."
    ),
    response_model=SearchOut,
    responses=problem_responses(404, 422),
)
def search(
    memory: MemoryDep,
    response: Response,
    q: QueryText,
    scope: ScopeDep,
    k: Annotated[int, Query(ge=1, le=MAX_K, description="How many hits.")] = 10,
    group: Annotated[
        Literal["auto", "window", "moment", "grasp"],
        Query(
            description="`auto` (default): touch answers are grasps (a touch stream's "
            "contiguous windows, one hit each, scored by the pooled embedding, spanning the "
            "grasp, members in `ids`), other senses one hit per item; `window`: one hit per "
            "stored item, touch windows too; `moment`: merge hits close in time into moments "
            "across senses; `grasp`: one hit per grasp of every sense, listed in `grasps`."
        ),
    ] = "auto",
    gap: Annotated[
        float | None,
        Query(ge=0.0, le=3600.0, description="With group=moment: seconds that still join hits."),
    ] = None,
    pool: GraspPool = "mean",
    sort: SortQ = None,
) -> SearchOut:
    t0 = time.perf_counter()
    if group == "moment":
        found = memory.search(q, k=k, group="moment", gap=gap, scope=scope, sort=sort)
        moments = [m for m in found if isinstance(m, Moment)]
        _timing(response, t0)
        best = [next(h for h in m.hits if h.id == m.best) for m in moments]
        return SearchOut(
            hits=[HitOut.model_validate(h, from_attributes=True) for h in best], moments=moments
        )
    if group == "grasp":
        grasps = memory.search(q, k=k, group="grasp", pool=pool, scope=scope, sort=sort)
        _timing(response, t0)
        return SearchOut(hits=_out(grasps).hits, grasps=grasps)
    hits = memory.search(q, k=k, group=group, pool=pool, scope=scope, sort=sort)
    _timing(response, t0)
    return _out(hits)


@router.post(
    "/like",
    dependencies=[Read],
    summary="Find moments similar to an example",
    description=(
        "Give one example: a touch window `frames` (raw sensor units unless `calibrated`), a "
        "`vector` of a registered sense, or a `text`. It is embedded by that sense and the "
        "sense's rows are searched."
    ),
    response_model=SearchOut,
    responses=problem_responses(404, 422, 503),
)
def search_like(body: SearchLikeIn, memory: MemoryDep, response: Response) -> SearchOut:
    t0 = time.perf_counter()
    scope = Scope(body.session, body.senses, body.source, body.after, body.before)
    if body.frames is not None:
        # the example's frame shape is its windowed sense's (a sense that is not windowed is
        # held to the shape the schema states and refuses the window itself, below)
        sense = memory.senses.get(body.sense)
        shape = frame_shape(sense) if isinstance(sense, WindowedSense) else STATED_FRAME
        window = as_window_array(body.frames, "K", "frames", shape, body.sense)
        opts = {"calibrated": body.calibrated}
        hits = memory.search_like(body.sense, window, k=body.k, options=opts, scope=scope)
    elif body.vector is not None:
        hits = memory.search_like(body.sense, k=body.k, vector=body.vector, scope=scope)
    else:
        hits = memory.search_like(body.sense, body.text, k=body.k, scope=scope)
    _timing(response, t0)
    return _out(hits)
