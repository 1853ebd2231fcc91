"""Touch writes over HTTP: one window, a batch of windows, or a binary ``.npy`` body.

Frames are RAW sensor units by default (what the glove's ADC reports, e.g. ~500-700 on the
STAG glove); the touch sense calibrates them. Send ``calibrated: true`` for frames already
calibrated to 0-1. Write path: see ``routers/items.py`` (threadpool, one commit, 201 after it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from tactus_memory.errors import InvalidInputError
from tactus_memory.service.arrays import NPY_TYPES, as_window, as_windows, load_npy, loads_strict
from tactus_memory.service.deps import (
    MemoryDep,
    SessionId,
    StateDep,
    TenantDep,
    TouchAvailable,
    WriteThreadsDep,
)
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SkippedOut, StoredOut, TouchBatchIn, TouchWindowIn
from tactus_memory.touch.profile import FRAME_SHAPE

router = APIRouter(prefix="/sessions/{session}", tags=["touch"])

NPY_DOC = (
    "Binary form: `Content-Type: application/x-npy`, the body an `.npy` array of shape "
    "(K, 32, 32) or (B, K, 32, 32) (any numeric dtype; `np.save` output), times in the "
    "query: `t` (once, or B times), optional `t_end` likewise, `calibrated`."
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


def _validate(model: type, obj: Any) -> Any:
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        errs = [{**e, "loc": ("body", *e.get("loc", ()))} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errs, body=obj) from None


@dataclass
class _Upload:
    """One touch POST, whatever its form: windows (the edge checked their shape) and their
    times, meta, ids and the calibrated flag."""

    windows: list[np.ndarray]
    t: list[float] | None
    t_end: list[float] | None
    meta: Any
    ids: list[str] | None
    calibrated: bool
    #: a batch (JSON ``windows``, a 4-D .npy): idle windows are skipped and named; one
    #: window alone that is idle is refused (422 idle-window), as ``Memory.add`` refuses it
    batch: bool = True


def _upload(
    ctype: str,
    raw: bytes,
    t: list[float] | None,
    t_end: list[float] | None,
    calibrated: bool,
) -> _Upload:
    if ctype in NPY_TYPES:
        arr = load_npy(raw, "npy body")
        if arr.ndim not in (3, 4) or arr.shape[-2:] != FRAME_SHAPE or 0 in arr.shape:
            raise InvalidInputError(
                f"npy body has shape {arr.shape}, expected (K, 32, 32) (one window) or "
                "(B, K, 32, 32) (a batch)"
            )
        windows = list(as_windows(arr[None] if arr.ndim == 3 else arr, "npy body"))
        if not t:
            raise InvalidInputError("query parameter 't' is required with an npy body")
        return _Upload(windows, t, t_end, None, None, calibrated, batch=arr.ndim == 4)
    if ctype not in ("application/json", "") and not ctype.endswith("+json"):
        raise HTTPException(
            415, f"unsupported content type {ctype!r}: use application/json or application/x-npy"
        )
    obj = loads_strict(raw)
    if not isinstance(obj, dict):
        raise InvalidInputError("body must be a JSON object with 'frames' or 'windows'")
    if "windows" in obj:
        batch: TouchBatchIn = _validate(TouchBatchIn, obj)
        windows = list(as_windows(batch.windows, "windows"))
        return _Upload(windows, batch.t, batch.t_end, batch.meta, batch.ids, batch.calibrated)
    one: TouchWindowIn = _validate(TouchWindowIn, obj)
    window = as_window(one.frames, "frames")
    t_end_one = None if one.t_end is None else [one.t_end]
    ids = None if one.id is None else [one.id]
    return _Upload([window], [one.t], t_end_one, one.meta, ids, one.calibrated, batch=False)


@router.post(
    "/touch",
    status_code=201,
    summary="Store touch windows (raw sensor units by default)",
    description=(
        'JSON, one window: `{"frames": (K,32,32), "t": 12.5, "t_end": 13.6, "meta": '
        '{...}, "calibrated": false}`. JSON batch: `{"windows": (B,K,32,32), "t": [B '
        "times], ...}`. Frames are RAW sensor units unless `calibrated` is true. A batch's "
        "idle windows (no contact) are skipped and listed in `skipped` (201, the rest "
        "stored); one window alone that is idle is refused (422 idle-window). " + NPY_DOC
    ),
    response_model=StoredOut,
    responses=problem_responses(404, 413, 415, 422, 503),
    openapi_extra={"requestBody": REQUEST_BODY},
    dependencies=[TouchAvailable],
)
async def add_touch(
    session: SessionId,
    request: Request,
    memory: MemoryDep,
    threads: WriteThreadsDep,
    state: StateDep,
    tenant: TenantDep,
    t: Annotated[list[float] | None, Query(description="npy body only: start time(s).")] = None,
    t_end: Annotated[list[float] | None, Query(description="npy body only: end time(s).")] = None,
    calibrated: Annotated[bool, Query(description="npy body only.")] = False,
) -> StoredOut:
    ctype = request.headers.get("content-type", "application/json").split(";")[0].strip().lower()
    raw = await request.body()
    up = _upload(ctype, raw, t, t_end, calibrated)
    # the edge checked shapes and sizes; the touch sense checks the rest (range, calibration,
    # idle) once, and one t (t_end) per window is the library's check (rows.per_item)
    ids = await state.write(
        tenant,
        session,
        "touch",
        up.windows,
        t=up.t,
        t_end=up.t_end,
        meta=up.meta,
        ids=up.ids,
        options={"calibrated": up.calibrated},
        skip_idle=up.batch,
    )
    skipped = [SkippedOut(index=i, reason=why) for i, why in getattr(ids, "skipped", ())]
    return StoredOut(ids=ids, count=len(ids), skipped=skipped)
