"""A touch POST body -> the one write it asks for: parsed, shape-checked and handed to the
group committer in ONE call on the write threads (never on the event loop).

The layers a touch window crosses: the route (``routers/touch.py``: reads the bytes) -> this
parse and :meth:`ServiceState.write_body` (one thread hop) -> the memory's write path
(``Memory.prepare_write``: the batch's times, meta, ids) -> the touch sense (``validate_many``:
range, calibration, idle, one numpy pass over the (B, K, 32, 32) array) -> the group
committer's commit (storage). The body's shape is checked here, once, with the message that
names what was sent; the sense looks at the batch's dimensions once, not window by window.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import HTTPException
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from tactus_memory.batches import WriteKwargs
from tactus_memory.errors import InvalidInputError
from tactus_memory.service.arrays import NPY_TYPES, as_touch_array, load_npy, loads_strict
from tactus_memory.service.schemas import TouchBatchIn, TouchWindowIn
from tactus_memory.touch.profile import FRAME_SHAPE


def _validate(model: type, obj: Any) -> Any:
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        errs = [{**e, "loc": ("body", *e.get("loc", ()))} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errs, body=obj) from None


def _windows(value: Any, what: str, ndim: int, shape: tuple[int, int], sense: str) -> np.ndarray:
    """The body's windows as one float32 array (B, K, H, W), H x W the sense's frame shape;
    ``ndim`` 3: one window sent as (K, H, W). The one shape check of a touch body."""
    if ndim == 3:
        return as_touch_array(value, "K", what, shape, sense)[None]
    return as_touch_array(value, "BK", what, shape, sense)


def touch_write(
    ctype: str,
    raw: bytes,
    t: list[float] | None,
    t_end: list[float] | None,
    calibrated: bool,
    sense: str = "touch",
    shape: tuple[int, int] = FRAME_SHAPE,
) -> tuple[np.ndarray, WriteKwargs]:
    """One touch POST (JSON window, JSON batch or ``.npy`` body) for the touch sense ``sense``
    whose frames are ``shape`` -> (windows (B, K, H, W) float32, the write's keywords for
    ``GroupCommitter.submit``). Idle windows are skipped and named (201 with ``skipped``), a
    batch's (JSON ``windows``, a 4-D ``.npy``) and one window alone alike: a robot that posts
    one window at a time gets no error for a resting hand, as the stream acknowledges it
    ``idle``. (``Memory.add`` in Python raises ``IdleWindowError`` for it.)"""
    if ctype in NPY_TYPES:
        arr = load_npy(raw, "npy body")
        h, w = shape
        if arr.ndim not in (3, 4) or arr.shape[-2:] != tuple(shape) or 0 in arr.shape:
            raise InvalidInputError(
                f"npy body has shape {arr.shape}, expected (K, {h}, {w}) (one window) or "
                f"(B, K, {h}, {w}) (a batch): sense {sense!r} reads {h}x{w} frames"
            )
        if not t:
            raise InvalidInputError("query parameter 't' is required with an npy body")
        windows = arr[None] if arr.ndim == 3 else arr
        kw: WriteKwargs = {"t": t, "t_end": t_end, "skip_idle": True}
        return windows, {**kw, "options": {"calibrated": calibrated}}
    if ctype not in ("application/json", "") and not ctype.endswith("+json"):
        raise HTTPException(
            415, f"unsupported content type {ctype!r}: use application/json or application/x-npy"
        )
    obj = loads_strict(raw)
    if not isinstance(obj, dict):
        raise InvalidInputError("body must be a JSON object with 'frames' or 'windows'")
    if "windows" in obj:
        batch: TouchBatchIn = _validate(TouchBatchIn, obj)
        return _windows(batch.windows, "windows", 4, shape, sense), {
            "t": batch.t,
            "t_end": batch.t_end,
            "meta": batch.meta,
            "ids": batch.ids,
            "options": {"calibrated": batch.calibrated},
            "skip_idle": True,
        }
    one: TouchWindowIn = _validate(TouchWindowIn, obj)
    return _windows(one.frames, "frames", 3, shape, sense), {
        "t": [one.t],
        "t_end": None if one.t_end is None else [one.t_end],
        "meta": one.meta,
        "ids": None if one.id is None else [one.id],
        "options": {"calibrated": one.calibrated},
        "skip_idle": True,
    }
