"""Windowed writes over HTTP: one window, a batch of windows, or a binary ``.npy`` body.

``POST /sessions/{id}/senses/{sense}/windows`` writes to any windowed sense (the
windowed-sense contract: its frame shape, its ``validate``); ``POST /sessions/{id}/touch``
(``?sense=``, default the glove) is the same write for touch, with bodies whose JSON schema
states the glove's 32x32 frames.

Touch frames are RAW sensor units by default (what the glove's ADC reports, e.g. ~500-700 on
the STAG glove); the touch sense calibrates them. Send ``calibrated: true`` for frames already
calibrated to 0-1. Write path: ``service/touch_body.py`` (the body parsed and validated once,
off the event loop; one group commit, 201 after it)."""

from __future__ import annotations

import functools
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from pydantic import BaseModel

from tactus_memory.service.deps import ServiceState, SessionId, StateDep, TenantDep, Write
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SkippedOut, StoredOut, TouchBatchIn, TouchWindowIn
from tactus_memory.service.tenancy import Tenant
from tactus_memory.service.touch_body import window_write
from tactus_memory.service.touch_senses import TouchSenseDep, WindowedSenseDep, frame_shape
from tactus_memory.service.window_schemas import WindowBatchIn, WindowIn
from tactus_memory.times import Seconds

router = APIRouter(prefix="/sessions/{session}", tags=["touch"])
#: the generic windowed write, any windowed sense by the name in the path
windows_router = APIRouter(prefix="/sessions/{session}", tags=["windows"])


def _npy_doc(shapes: str) -> str:
    return (
        "Binary form: `Content-Type: application/x-npy`, the body an `.npy` array of shape "
        f"{shapes}; any numeric dtype; `np.save` output), times in the query: `t` (once, or B "
        "times), optional `t_end` likewise, `calibrated`."
    )


NPY_DOC = _npy_doc("(K, H, W) or (B, K, H, W) (H x W the sense's frame shape: 32x32 for the glove")


def _request_body(one: Any, batch: Any, example: bool) -> dict[str, Any]:
    """The OpenAPI request body of a windowed write: JSON (one window or a batch) or ``.npy``."""
    json_body: dict[str, Any] = {
        "schema": {"oneOf": [one.model_json_schema(), batch.model_json_schema()]}
    }
    if example:
        json_body["example"] = one.model_config["json_schema_extra"]["examples"][0]
    return {
        "required": True,
        "content": {
            "application/json": json_body,
            "application/x-npy": {"schema": {"type": "string", "format": "binary"}},
        },
    }


REQUEST_BODY = _request_body(TouchWindowIn, TouchBatchIn, example=True)


@router.post(
    "/touch",
    dependencies=[Write],
    status_code=201,
    summary="Store touch windows (raw sensor units by default)",
    description=(
        'JSON, one window: `{"frames": (K,H,W), "t": 12.5, "t_end": 13.6, "meta": '
        '{...}, "calibrated": false}`. JSON batch: `{"windows": (B,K,H,W), "t": [B '
        "times], ...}`; H x W is the frame shape of the touch sense `sense` names (default "
        "`touch`, the 32x32 glove; `GET /senses` lists each one's `shape`): a window of "
        "another shape is a 422 naming both, an unknown sense a 404. Frames are RAW sensor "
        "units unless `calibrated` is true. Idle windows (no contact) are skipped and listed "
        "in `skipped` (201, the rest stored), in a batch and alone alike (one idle window "
        'alone: 201 with `"ids": []` and `"skipped": [{"index": 0, "reason": "idle"}]`). ' + NPY_DOC
    ),
    response_model=StoredOut,
    responses=problem_responses(404, 413, 415, 422, 503),
    openapi_extra={"requestBody": REQUEST_BODY},
)
async def add_touch(
    session: SessionId,
    request: Request,
    state: StateDep,
    tenant: TenantDep,
    t: Annotated[list[Seconds] | None, Query(description="npy body only: start time(s).")] = None,
    t_end: Annotated[list[Seconds] | None, Query(description="npy body only: end time(s).")] = None,
    calibrated: Annotated[bool, Query(description="npy body only.")] = False,
    *,
    sense: TouchSenseDep,
) -> StoredOut:
    bodies = (TouchWindowIn, TouchBatchIn)
    return await _store(session, request, state, tenant, t, t_end, calibrated, sense, bodies)


@windows_router.post(
    "/senses/{sense}/windows",
    dependencies=[Write],
    status_code=201,
    summary="Store windows of any windowed sense (touch, an IMU...)",
    description=(
        'JSON, one window: `{"frames": (K, *F), "t": 12.5, ...}`; JSON batch: `{"windows": '
        '(B, K, *F), "t": [B times], ...}`, F the frame shape of the windowed sense the path '
        "names (`GET /senses`: `shape`): a window of another shape is a 422 naming both, an "
        "unknown sense a 404, a sense that is not windowed a 422. The same write as "
        "`POST /sessions/{id}/touch` (which is this route for touch), idle windows skipped "
        "and listed in `skipped`. " + _npy_doc("(K, *F) or (B, K, *F) (F the sense's frame shape")
    ),
    response_model=StoredOut,
    responses=problem_responses(404, 413, 415, 422, 503),
    openapi_extra={"requestBody": _request_body(WindowIn, WindowBatchIn, example=False)},
)
async def add_windows(
    session: SessionId,
    request: Request,
    state: StateDep,
    tenant: TenantDep,
    t: Annotated[list[Seconds] | None, Query(description="npy body only: start time(s).")] = None,
    t_end: Annotated[list[Seconds] | None, Query(description="npy body only: end time(s).")] = None,
    calibrated: Annotated[bool, Query(description="npy body only.")] = False,
    *,
    sense: WindowedSenseDep,
) -> StoredOut:
    bodies = (WindowIn, WindowBatchIn)
    return await _store(session, request, state, tenant, t, t_end, calibrated, sense, bodies)


async def _store(
    session: str,
    request: Request,
    state: ServiceState,
    tenant: Tenant,
    t: list[float] | None,
    t_end: list[float] | None,
    calibrated: bool,
    sense: Any,
    bodies: tuple[type[BaseModel], type[BaseModel]],
) -> StoredOut:
    """One windowed write of ``sense`` (either route): the body parsed, checked against the
    sense's frame shape and validated by the sense on the write threads, off the event loop
    (service/touch_body.py), then one group commit."""
    ctype = request.headers.get("content-type", "application/json").split(";")[0].strip().lower()
    raw = await request.body()
    parse = functools.partial(
        window_write, ctype, raw, t, t_end, calibrated, sense.name, frame_shape(sense), bodies
    )
    ids = await state.write_body(tenant, session, sense.name, parse)
    skipped = [SkippedOut(index=i, reason=why) for i, why in getattr(ids, "skipped", ())]
    return StoredOut(ids=ids, count=len(ids), skipped=skipped)
