"""The bodies of the generic windowed routes (``/sessions/{id}/senses/{sense}/windows``): the
touch bodies' fields (``schemas.TouchWindowIn``, ``TouchBatchIn``: times, meta, ids,
``calibrated``), with frames of any shape: a window of a windowed sense is (K, *F), F its
frame shape (``GET /senses``: ``shape``; an IMU's (6,), the glove's (32, 32)), which one schema
cannot state for every sense, so it is checked after parsing against the sense the path names
(``service/arrays.py``: ``as_window_array``), with a 422 that names both shapes."""

from __future__ import annotations

from typing import Any

from pydantic import Field, create_model

from tactus_memory.limits import MAX_WINDOW_FRAMES
from tactus_memory.service.schemas import (
    MAX_JSON_WINDOWS,
    Strict,
    TouchBatchIn,
    TouchWindowIn,
)

#: (K, *F) one window of frames of any shape F: nested lists of numbers
AnyWindow = list[Any]
WINDOW_DESC = (
    "(K, *F) frames, F the frame shape of the sense the path names (`GET /senses`: `shape`; "
    "an IMU's (6,), the glove's (32, 32)). RAW sensor units unless calibrated=true, for a "
    "sense that calibrates."
)


def _with_frames(model: type[Strict], name: str, doc: str, field: str, new: tuple[Any, Any]) -> Any:
    """``model``'s fields, ``field`` replaced by ``new`` ((annotation, Field)), as ``name``."""
    fields: dict[str, Any] = {n: (f.annotation, f) for n, f in model.model_fields.items()}
    fields[field] = new
    return create_model(name, __base__=Strict, __doc__=doc, **fields)


#: one window of a windowed sense: ``frames`` (K, *F), the rest as ``TouchWindowIn``
WindowIn = _with_frames(
    TouchWindowIn,
    "WindowIn",
    "One window of a windowed sense: K frames of its frame shape.",
    "frames",
    (AnyWindow, Field(min_length=1, max_length=MAX_WINDOW_FRAMES, description=WINDOW_DESC)),
)
#: a batch of windows of one windowed sense: ``windows`` (B, K, *F), the rest as ``TouchBatchIn``
WindowBatchIn = _with_frames(
    TouchBatchIn,
    "WindowBatchIn",
    "Several windows of one windowed sense and session, stored in one commit.",
    "windows",
    (
        list[AnyWindow],
        Field(
            min_length=1,
            max_length=MAX_JSON_WINDOWS,
            description="(B, K, *F) windows (F as for `frames`); every window has the same K.",
        ),
    ),
)
