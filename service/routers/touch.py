"""Touch writes over HTTP: one window, a batch of windows, or a binary ``.npy`` body.

Frames are RAW sensor units by default (what the glove's ADC reports, e.g. ~500-700 on the
STAG glove); the touch sense calibrates them. Send ``calibrated: true`` for frames already
calibrated to 0-1. Write path: ``service/touch_body.py`` (the body parsed and validated once,
off the event loop; one group commit, 201 after it)."""

from __future__ import annotations

import functools
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request

from tactus_memory.service.deps import SessionId, StateDep, TenantDep
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SkippedOut, StoredOut, TouchBatchIn, TouchWindowIn
from tactus_memory.service.touch_body import touch_write
from tactus_memory.service.touch_senses import TouchSenseDep, frame_shape
from tactus_memory.times import Seconds

router = APIRouter(prefix="/sessions/{session}", tags=["touch"])

NPY_DOC = (
    "Binary form: `Content-Type: application/x-npy`, the body an `.npy` array of shape "
    "(K, H, W) or (B, K, H, W) (H x W the sense's frame shape: 32x32 for the glove; any "
    "numeric dtype; `np.save` output), times in the query: `t` (once, or B times), optional "
    "`t_end` likewise, `calibrated`."
)

REQUEST_BODY: dict[str, Any] = {
    "required": True,
    "content": {
        "application/json": {
            "schema": {
                "oneOf": [
                    TouchWindowIn.model_json_schema(),
                    TouchBatchIn.model_json_schema(),
                ]
            },
            "example": TouchWindowIn.model_config["json_schema_extra"]["examples"][0],  # type: ignore[index]
        },
        "application/x-npy": {"schema": {"type": "string", "format": "binary"}},
    },
}


@router.post(
    "/touch",
    status_code=201,
    summary="Store touch windows (raw sensor units by default)",
    description=(
        'JSON, one window: `{"frames": (K,H,W), "t": 12.5, "t_end": 13.6, "meta": '
        '{...}, "calibrated": false}`. JSON batch: `{"windows": (B,K,H,W), "t": [B '
        "times], ...}`; H x W is the frame shape of the touch sense `sense` names (default "
        "`touch`, the 32x32 glove; `GET /senses` lists each one's `shape`): a window of "
        "another shape is a 422 naming both, an unknown sense a 404. Frames are RAW sensor "
        "units unless `calibrated` is true. A batch's "
        "idle windows (no contact) are skipped and listed in `skipped` (201, the rest "
        "stored); one window alone that is idle is refused (422 idle-window). " + NPY_DOC
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
    ctype = request.headers.get("content-type", "application/json").split(";")[0].strip().lower()
    raw = await request.body()
    # the body goes to the write path once: parsed, shape-checked (against the sense's
    # frame shape) and validated by the touch sense on the write threads, off the event
    # loop (service/touch_body.py)
    parse = functools.partial(
        touch_write, ctype, raw, t, t_end, calibrated, sense.name, frame_shape(sense)
    )
    ids = await state.write_body(tenant, session, sense.name, parse)
    skipped = [SkippedOut(index=i, reason=why) for i, why in getattr(ids, "skipped", ())]
    return StoredOut(ids=ids, count=len(ids), skipped=skipped)
