"""A windowed POST body (a touch window, an IMU window...) -> the one write it asks for:
parsed, shape-checked against the sense's frame shape and handed to the group committer in ONE
call on the write threads (never on the event loop).

The layers a touch window crosses: the route (``routers/touch.py``: reads the bytes; the
generic ``/sessions/{id}/senses/{sense}/windows`` the same) -> this parse and
:meth:`ServiceState.write_body` (one thread hop) -> the memory's write path
(``Memory.prepare_write``: the batch's times, meta, ids) -> the sense (``validate_many``: for
touch range, calibration, idle, one numpy pass over the (B, K, 32, 32) array) -> the group
committer's commit (storage). The body's shape is checked here, once, with the message that
names what was sent; the sense looks at the batch's dimensions once, not window by window.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import HTTPException
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ValidationError

from tactus_memory.batches import WriteKwargs
from tactus_memory.errors import InvalidInputError
from tactus_memory.service.arrays import (
    NPY_TYPES,
    as_window_array,
    load_npy,
    loads_strict,
    shape_name,
)
from tactus_memory.service.schemas import TouchBatchIn, TouchWindowIn


def _validate(model: type[BaseModel], obj: Any) -> Any:
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        errs = [{**e, "loc": ("body", *e.get("loc", ()))} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errs, body=obj) from None


def _windows(value: Any, what: str, one: bool, shape: tuple[int, ...], sense: str) -> np.ndarray:
    """The body's windows as one float32 array (B, K, *shape), ``shape`` the sense's frame
    shape; ``one``: one window sent as (K, *shape). The one shape check of a windowed body."""
    if one:
        return as_window_array(value, "K", what, shape, sense)[None]
    return as_window_array(value, "BK", what, shape, sense)


def window_write(
    ctype: str,
    raw: bytes,
    t: list[float] | None,
    t_end: list[float] | None,
    calibrated: bool,
    sense: str,
    shape: tuple[int, ...],
    bodies: tuple[type[BaseModel], type[BaseModel]] = (TouchWindowIn, TouchBatchIn),
) -> tuple[np.ndarray, WriteKwargs]:
    """One windowed POST (JSON window, JSON batch or ``.npy`` body) for the windowed sense
    ``sense`` whose frames are ``shape`` -> (windows (B, K, *shape) float32, the keywords for
    ``GroupCommitter.submit``); ``bodies``: the JSON body models (one window, a batch: the
    touch route's state the glove's 32x32 frames, the generic route's any shape). Idle windows
    are skipped and named (201 with ``skipped``), a batch's (JSON ``windows``, a ``.npy`` of
    B windows) and one window alone alike: a robot that posts
    one window at a time gets no error for a resting hand, as the stream acknowledges it
    ``idle``. (``Memory.add`` in Python raises ``IdleWindowError`` for it.)"""
    if ctype in NPY_TYPES:
        arr = load_npy(raw, "npy body")
        n, dims = len(shape), ", ".join(map(str, shape))
        if arr.ndim not in (n + 1, n + 2) or arr.shape[-n:] != tuple(shape) or 0 in arr.shape:
            raise InvalidInputError(
                f"npy body has shape {arr.shape}, expected (K, {dims}) (one window) or "
                f"(B, K, {dims}) (a batch): sense {sense!r} reads {shape_name(shape)} frames"
            )
        if not t:
            raise InvalidInputError("query parameter 't' is required with an npy body")
        windows = arr[None] if arr.ndim == n + 1 else arr
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
        batch: TouchBatchIn = _validate(bodies[1], obj)
        return _windows(batch.windows, "windows", False, shape, sense), {
            "t": batch.t,
            "t_end": batch.t_end,
            "meta": batch.meta,
            "ids": batch.ids,
            "options": {"calibrated": batch.calibrated},
            "skip_idle": True,
        }
    one: TouchWindowIn = _validate(bodies[0], obj)
    return _windows(one.frames, "frames", True, shape, sense), {
        "t": [one.t],
        "t_end": None if one.t_end is None else [one.t_end],
        "meta": one.meta,
        "ids": None if one.id is None else [one.id],
        "options": {"calibrated": one.calibrated},
        "skip_idle": True,
    }
