"""Places (``tactus_memory.memory.places``): a session's poses in, ``/where`` and ``/at`` out.

Every search and temporal route also takes ``near=x,y,z,r`` and ``frame=`` (``deps.ScopeDep``);
``GET /at`` takes its place as ``x``, ``y``, ``z``, ``r`` and refuses ``near``
(``deps.PlaceScopeDep``).
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import ID_PATTERN, MAX_COORDINATE, MAX_ID_CHARS, MAX_K, SOURCE_PATTERN
from tactus_memory.matching import DEFAULT_MOMENT_GAP
from tactus_memory.service.arrays import NPY_TYPES, loads_strict, read_npy
from tactus_memory.service.deps import MemoryDep, PlaceScopeDep, QueryText, ScopeDep, SessionId
from tactus_memory.service.place_schemas import (
    AtOut,
    PlacesOut,
    PosesIn,
    PosesStoredOut,
    TrajectoriesOut,
)
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.routers.temporal import MatchDep
from tactus_memory.where import DEFAULT_FRAME

router = APIRouter(tags=["places"])

POSES_BODY: dict[str, Any] = {
    "required": True,
    "content": {
        "application/json": {
            "schema": PosesIn.model_json_schema(),
            "example": PosesIn.model_config["json_schema_extra"]["examples"][0],  # type: ignore[index]
        },
        "application/x-npy": {"schema": {"type": "string", "format": "binary"}},
    },
}
FrameQ = Annotated[str, Query(pattern=ID_PATTERN, max_length=MAX_ID_CHARS)]
Coordinate = Annotated[float, Query(ge=-MAX_COORDINATE, le=MAX_COORDINATE, description="m")]
SourceQ = Annotated[str, Query(pattern=SOURCE_PATTERN, max_length=MAX_ID_CHARS)]


def _poses(ctype: str, raw: bytes, frame: str, source: str) -> PosesIn | tuple[np.ndarray, ...]:
    """The body as (t, position, orientation) arrays: JSON (:class:`PosesIn`) or an ``.npy``
    array (N, 4) ``[t, x, y, z]`` or (N, 8) ``[t, x, y, z, qx, qy, qz, qw]``."""
    if ctype in NPY_TYPES:
        arr = read_npy(raw, "npy body").astype(np.float64)
        if arr.ndim != 2 or arr.shape[1] not in (4, 8):
            raise InvalidInputError(
                f"npy body must be (N, 4) [t, x, y, z] or (N, 8) [t, x, y, z, qx, qy, qz, qw], "
                f"got shape {arr.shape}"
            )
        return arr[:, 0], arr[:, 1:4], (arr[:, 4:8] if arr.shape[1] == 8 else None)
    if ctype not in ("application/json", "") and not ctype.endswith("+json"):
        raise HTTPException(
            415, f"unsupported content type {ctype!r}: use application/json or application/x-npy"
        )
    try:
        return PosesIn.model_validate(loads_strict(raw))
    except ValidationError as exc:
        errs = [{**e, "loc": ("body", *e.get("loc", ()))} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errs) from None


@router.post(
    "/sessions/{session}/poses",
    status_code=201,
    summary="Store a session's poses (its trajectory)",
    description=(
        "JSON: `{t: [N], position: [[x, y, z] x N], orientation: [[qx, qy, qz, qw] x N] | "
        "null, frame: 'map', source: 'odom'}`; or `Content-Type: application/x-npy` with an "
        "(N, 4) `[t, x, y, z]` or (N, 8) `[t, x, y, z, qx, qy, qz, qw]` float64 array and "
        "`frame`/`source` in the query. Times must strictly increase; quaternions be unit. "
        "The session's items the poses cover are placed (also those already stored)."
    ),
    response_model=PosesStoredOut,
    responses=problem_responses(409, 413, 415, 422),
    openapi_extra={"requestBody": POSES_BODY},
)
async def add_poses(
    session: SessionId,
    request: Request,
    memory: MemoryDep,
    frame: Annotated[FrameQ, Query(description="npy body only.")] = DEFAULT_FRAME,
    source: Annotated[SourceQ, Query(description="npy body only.")] = "",
) -> PosesStoredOut:
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    got = _poses(ctype, await request.body(), frame, source)
    if isinstance(got, PosesIn):
        ori = None if got.orientation is None else got.orientation
        args = (got.t, got.position, ori, got.frame, got.source)
    else:
        args = (*got, frame, source)
    n = await run_in_threadpool(memory.add_poses, session, *args)
    return PosesStoredOut(session=session, count=n)


@router.get(
    "/sessions/{session}/poses",
    summary="A session's trajectory, one per frame",
    description="404 for a session with neither items nor poses.",
    response_model=TrajectoriesOut,
    responses=problem_responses(404, 422),
)
def get_poses(
    session: SessionId,
    memory: MemoryDep,
    frame: Annotated[FrameQ | None, Query(description="Only this frame.")] = None,
) -> TrajectoriesOut:
    trajectories = memory.trajectory(session, frame)
    if not trajectories and not memory.trajectory(session):
        memory.session(session)  # 404 for a session that has neither items nor poses
    return TrajectoriesOut(session=session, trajectories=trajectories)


@router.get(
    "/where",
    summary="Where did something happen?",
    description=(
        "The places where moments matching `q` happened, best first: each with its position "
        "and frame, its span, score and evidence. Moments with no placed member are left out. "
        "Takes the scope (session, sense, source, after, before, near, frame) and match bar."
    ),
    responses=problem_responses(404, 422),
)
def where(
    memory: MemoryDep,
    q: QueryText,
    scope: ScopeDep,
    match: MatchDep,
    gap: Annotated[float, Query(ge=0.0, le=1e9)] = DEFAULT_MOMENT_GAP,
    k: Annotated[int, Query(ge=1, le=MAX_K, description="How many places.")] = 10,
) -> PlacesOut:
    return PlacesOut(query=q, places=memory.where(q, k, gap=gap, scope=scope, match=match))


@router.get(
    "/at",
    summary="What happened near a place?",
    description="Items placed within `r` metres of (`x`, `y`, `z`), in time order.",
    responses=problem_responses(404, 422),
)
def at(
    request: Request,
    memory: MemoryDep,
    scope: PlaceScopeDep,
    x: Coordinate,
    y: Coordinate,
    z: Coordinate,
    r: Annotated[float, Query(gt=0.0, le=MAX_COORDINATE, description="Radius (m).")],
) -> AtOut:
    # the schema does not offer near (the place is x, y, z and r); one sent anyway is refused,
    # never ignored as if the answer were filtered by it
    if "near" in request.query_params:
        raise InvalidInputError("/at takes the place as x, y, z and r; drop near")
    filters = dataclasses.asdict(scope)
    filters.pop("near")
    items = memory.at((x, y, z), r, **filters)
    return AtOut(position=(x, y, z), radius=r, items=items)
