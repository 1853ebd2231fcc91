"""Search: natural language (GET /search) and by example (POST /search/like)."""

from __future__ import annotations

import time
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from tactus_memory.service.arrays import as_window
from tactus_memory.service.deps import ID_PATTERN, MemoryDep
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SENSE_PATTERN, HitOut, SearchLikeIn, SearchOut

router = APIRouter(prefix="/search", tags=["search"])

K_MAX = 1000


def _timing(response: Response, t0: float) -> None:
    """``Server-Timing: library;dur=<ms>``: the time spent in the library call (embedding
    and search), so a client can tell the service's own overhead from the library's work."""
    response.headers["Server-Timing"] = f"library;dur={(time.perf_counter() - t0) * 1e3:.3f}"


def _out(hits: list) -> SearchOut:
    return SearchOut(hits=[HitOut.model_validate(h, from_attributes=True) for h in hits])


@router.get(
    "",
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
    q: Annotated[
        str,
        Query(
            min_length=1,
            max_length=8192,
            description="The query in words.",
            examples=["holding a warm mug"],
        ),
    ],
    k: Annotated[int, Query(ge=1, le=K_MAX, description="How many hits.")] = 10,
    sense: Annotated[
        list[str] | None,
        Query(
            description="Restrict to these senses (repeat the parameter).",
            json_schema_extra={"items": {"type": "string", "pattern": SENSE_PATTERN}},
        ),
    ] = None,
    session: Annotated[str | None, Query(pattern=ID_PATTERN, max_length=128)] = None,
    after: Annotated[float | None, Query(description="Items still going on at or after.")] = None,
    before: Annotated[float | None, Query(description="Items started at or before.")] = None,
    group: Annotated[
        Literal["moment"] | None,
        Query(description="`moment`: merge hits close in time into moments across senses."),
    ] = None,
    gap: Annotated[
        float | None,
        Query(ge=0.0, le=3600.0, description="With group=moment: seconds that still join hits."),
    ] = None,
) -> SearchOut:
    t0 = time.perf_counter()
    filters = {"senses": sense, "session": session, "after": after, "before": before}
    if group == "moment":
        moments = memory.search(q, k=k, group="moment", gap=gap, **filters)
        _timing(response, t0)
        best = [next(h for h in m.hits if h.id == m.best) for m in moments]
        return SearchOut(
            hits=[HitOut.model_validate(h, from_attributes=True) for h in best], moments=moments
        )
    hits = memory.search(q, k=k, **filters)
    _timing(response, t0)
    return _out(hits)


@router.post(
    "/like",
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
    filters = {
        "senses": body.senses,
        "session": body.session,
        "after": body.after,
        "before": body.before,
    }
    if body.frames is not None:
        window = as_window(body.frames)
        opts = {"calibrated": body.calibrated}
        hits = memory.search_like(body.sense, window, k=body.k, options=opts, **filters)
    elif body.vector is not None:
        hits = memory.search_like(body.sense, k=body.k, vector=body.vector, **filters)
    else:
        hits = memory.search_like(body.sense, body.text, k=body.k, **filters)
    _timing(response, t0)
    return _out(hits)
