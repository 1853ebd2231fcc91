"""The memory browser: the page at ``/`` and the heat-map PNGs it shows.

``page_router`` (no token: it is static HTML/JS/CSS and holds no data; the page sends the
token the user types on every API call) serves ``/`` and ``/static/<file>`` from
``service/static``. ``router`` (behind the token like every data route) draws touch windows:
``GET /items/{id}/touch.png`` for a stored window (``/touch.json``: its numbers, for the value
under the pointer) and ``POST /render/touch.png`` for a window the user is about to search
with. Both draw through the sense's ``drawer`` (the windowed-sense contract,
``service/touch_senses.py: drawer_of``): for touch the renderer of the evaluation report
(``tactus_memory.touch.render``).
"""

from __future__ import annotations

import functools
from pathlib import Path as FsPath
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import FileResponse, HTMLResponse, Response
from pydantic import Field
from starlette.concurrency import run_in_threadpool

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import SENSE_NAME_PATTERN
from tactus_memory.senses.windowed import WindowDrawer, WindowLayout
from tactus_memory.service.arrays import as_window_array
from tactus_memory.service.deps import ItemIdPath, MemoryDep, Open, Read
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import Strict, Window
from tactus_memory.service.touch_senses import (
    DEFAULT_TOUCH_SENSE,
    default_sense_class,
    drawer_of,
)

STATIC = FsPath(__file__).resolve().parent.parent / "static"
STATIC_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
    ".ico": "image/x-icon",
}
PNG = "image/png"
PNG_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"content": {PNG: {"schema": {"type": "string", "format": "binary"}}}}
}

page_router = APIRouter(include_in_schema=False)
router = APIRouter(tags=["browser"])

#: the heat maps' defaults: the default touch sense's (the glove: 4 px per taxel, 16 frames)
DRAW = default_sense_class().draw_defaults
SCALE, MAX_FRAMES = DRAW["scale"], DRAW["max_frames"]
Scale = Annotated[int, Query(ge=1, le=16, description="Pixels per taxel.")]
MaxFrames = Annotated[int, Query(ge=1, le=64, description="Most frames drawn (evenly spread).")]
Columns = Annotated[
    int | None, Query(ge=1, le=64, description="Frames per row (default: all in one row).")
]
Legend = Annotated[bool, Query(description="Draw the colour bar under the frames.")]
Outline = Annotated[
    bool,
    Query(
        description="Outline the sensor's parts on every frame (a hand's regions: thumb, "
        "fingers, palm; or a profile's pads), where the sense knows them; the page does."
    ),
]


def _layout(
    scale: Scale = SCALE,
    max_frames: MaxFrames = MAX_FRAMES,
    columns: Columns = None,
    outline: Outline = False,
) -> WindowLayout:
    """How the query asks a window to be drawn (the same parameters on every heat map)."""
    return WindowLayout(scale=scale, max_frames=max_frames, columns=columns, outline=outline)


#: ``scale``, ``max_frames`` and ``columns`` from the query, as drawing keywords
LayoutDep = Annotated[WindowLayout, Depends(_layout)]


# ----------------------------------------------------------------------------- the page
@page_router.get("/", dependencies=[Open], response_class=HTMLResponse)
def index() -> Response:
    return _static_file("index.html")


@page_router.get("/static/{name}", dependencies=[Open])
def static_file(name: str) -> Response:
    return _static_file(name)


def _static_file(name: str) -> Response:
    path = (STATIC / name).resolve()
    if path.parent != STATIC or path.suffix not in STATIC_TYPES or not path.is_file():
        raise HTTPException(404, f"no static file {name!r}")
    # no-cache: browsers revalidate (ETag), so a new release is never served stale
    return FileResponse(
        path, media_type=STATIC_TYPES[path.suffix], headers={"Cache-Control": "no-cache"}
    )


# ----------------------------------------------------------------------------- heat maps
def _window_of(raw: Any, shape: tuple[int, ...]) -> tuple[np.ndarray | None, bool | None]:
    """The (K, *shape) frames inside a stored windowed item, ``shape`` its sense's frame shape
    ((H, W) for touch), and whether they are calibrated (None: unknown, decided from the
    values)."""
    calibrated = getattr(raw, "calibrated", None)
    if isinstance(raw, dict):
        calibrated = raw.get("calibrated")
        raw = raw.get("frames", raw.get("window"))
    elif not isinstance(raw, np.ndarray):
        raw = getattr(raw, "frames", getattr(raw, "window", raw))
    if raw is None or isinstance(raw, (str, bytes)):
        return None, None
    arr = np.asarray(raw)
    if arr.ndim == len(shape):
        arr = arr[None]
    if arr.ndim != len(shape) + 1 or arr.shape[1:] != tuple(shape) or arr.dtype == object:
        return None, None
    return arr, None if calibrated is None else bool(calibrated)


def _png(body: bytes) -> Response:
    return Response(body, media_type=PNG, headers={"Cache-Control": "private, max-age=300"})


def _item_window(memory: Any, item_id: str) -> tuple[np.ndarray, bool | None, WindowDrawer]:
    item = memory.get_item(item_id)  # NotFoundError -> 404
    drawer = drawer_of(memory, item.sense)
    window, calibrated = _window_of(item.raw, drawer.frame_shape)
    if window is None:
        raise InvalidInputError(
            f"item {item_id!r} (sense {item.sense!r}) holds no touch window to draw"
        )
    return window, calibrated, drawer


def _item_png(memory: Any, item_id: str, layout: WindowLayout, legend: bool) -> bytes:
    window, calibrated, drawer = _item_window(memory, item_id)
    return drawer.png(window, calibrated=calibrated, legend=legend, layout=layout)


def _item_values(memory: Any, item_id: str, layout: WindowLayout) -> dict[str, Any]:
    window, calibrated, drawer = _item_window(memory, item_id)
    return drawer.values(window, calibrated=calibrated, layout=layout)


@router.get(
    "/items/{item_id}/touch.png",
    dependencies=[Read],
    summary="A stored touch window as a pressure heat map (PNG)",
    description=(
        "One image per frame (one row, or `columns` per row): calibrated pressure on the "
        "sensor's taxels through the magma colour map, from the contact level (darkest) to "
        "the window's 99th percentile (brightest), gamma 0.5, with a colour bar stating both; "
        "each frame is the sense's H x W grid (the glove: 32x32, whose pixels that are not "
        "taxels are drawn in the background colour, as are the gaps between a hand's pads). "
        "422 when the item holds no touch window (e.g. a text note)."
    ),
    response_class=Response,
    responses={**PNG_RESPONSE, **problem_responses(404, 422)},
)
async def touch_png(
    item_id: ItemIdPath,
    memory: MemoryDep,
    layout: LayoutDep,
    legend: Legend = True,
) -> Response:
    png = await run_in_threadpool(_item_png, memory, item_id, layout, legend)
    return _png(png)


@router.get(
    "/items/{item_id}/touch.json",
    dependencies=[Read],
    summary="The numbers behind a stored touch window's heat map",
    description=(
        "For the same query as `touch.png`: `values` (K', H, W) calibrated pressure of the "
        "drawn frames, `frames` their indices in the window, `taxels` the (H, W) taxel mask, "
        "`scale` (lo, hi, gamma, colormap) and `layout` (columns, rows, scale, gap, "
        "frame_rows, frame_cols, width, height of the frames in pixels) so a pointer position "
        "maps to a taxel."
    ),
    responses=problem_responses(404, 422),
)
async def touch_json(
    item_id: ItemIdPath,
    memory: MemoryDep,
    layout: LayoutDep,
) -> dict[str, Any]:
    return await run_in_threadpool(_item_values, memory, item_id, layout)


class RenderIn(Strict):
    """A touch window to draw (e.g. the example the user is about to search with)."""

    frames: Window = Field(description="(K, H, W) pressure frames, H x W the sense's shape.")
    calibrated: bool | None = Field(
        None, description="true: 0..1; false: raw sensor units; null: decided from the values."
    )
    sense: str = Field(
        DEFAULT_TOUCH_SENSE,
        pattern=SENSE_NAME_PATTERN,
        description="The touch sense whose sensor the window is from (its shape, calibration "
        "and taxel layout); default the glove.",
    )


@router.post(
    "/render/touch.png",
    dependencies=[Read],
    summary="Draw a touch window as a pressure heat map (PNG)",
    description="The same picture as `GET /items/{id}/touch.png`, for a window in the body.",
    response_class=Response,
    responses={**PNG_RESPONSE, **problem_responses(404, 413, 422)},
)
async def render_touch_png(
    body: RenderIn,
    layout: LayoutDep,
    memory: MemoryDep,
    legend: Legend = True,
) -> Response:
    drawer = drawer_of(memory, body.sense)
    window = as_window_array(body.frames, "K", "frames", drawer.frame_shape, body.sense)
    png = await run_in_threadpool(
        functools.partial(drawer.png, calibrated=body.calibrated, legend=legend, layout=layout),
        window,
    )
    return _png(png)
