"""Images: thumbnails of stored image items and search by an uploaded example image.

``GET /items/{id}/image.png`` draws the thumbnail an image item keeps (the page shows it in
hits, moments and the timeline's evidence); ``POST /search/like/image`` embeds an uploaded
PNG/JPEG/WebP with the image sense and searches (image -> image by default; name ``senses``
to search others, e.g. text, with the same vector). Text -> image is plain ``GET /search``.
"""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Query, Response, UploadFile
from starlette.concurrency import run_in_threadpool

from tactus_memory.adapters.image import THUMBNAIL_SIDE
from tactus_memory.errors import CapabilityError, InvalidInputError
from tactus_memory.limits import ID_PATTERN, MAX_ID_CHARS, MAX_K
from tactus_memory.limits import SENSE_NAME_PATTERN as SENSE_PATTERN
from tactus_memory.service.deps import ItemIdPath, MemoryDep
from tactus_memory.service.images import decode_image, encode_png, is_image_array
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import HitOut, SearchOut
from tactus_memory.times import Seconds

router = APIRouter(tags=["images"])

PNG = "image/png"


def _item_image(memory: Any, item_id: str, size: int) -> bytes:
    item = memory.get_item(item_id)  # NotFoundError -> 404
    if not is_image_array(item.raw):
        raise InvalidInputError(f"item {item_id!r} (sense {item.sense!r}) holds no image to draw")
    return encode_png(item.raw, size)


@router.get(
    "/items/{item_id}/image.png",
    summary="A stored image item's thumbnail (PNG)",
    description=(
        f"The thumbnail the item keeps (longest side <= {THUMBNAIL_SIDE} px), shrunk to "
        "`size`. 422 when the item holds no image (e.g. a text note)."
    ),
    response_class=Response,
    responses={
        200: {"content": {PNG: {"schema": {"type": "string", "format": "binary"}}}},
        **problem_responses(404, 422),
    },
)
async def image_png(
    item_id: ItemIdPath,
    memory: MemoryDep,
    size: Annotated[
        int, Query(ge=8, le=THUMBNAIL_SIDE, description="Longest side in pixels.")
    ] = THUMBNAIL_SIDE,
) -> Response:
    png = await run_in_threadpool(_item_image, memory, item_id, size)
    return Response(png, media_type=PNG, headers={"Cache-Control": "private, max-age=300"})


@router.post(
    "/search/like/image",
    summary="Find items similar to an uploaded image",
    description=(
        "Multipart: `file` (PNG/JPEG/WebP), optional `k`, `sense` (the image sense, default "
        "`image`), `senses` (repeat; default: that sense), `session`, `after`, `before`. "
        "400 when the memory's space has no vision."
    ),
    response_model=SearchOut,
    responses=problem_responses(400, 404, 413, 422),
)
async def search_like_image(
    memory: MemoryDep,
    response: Response,
    file: Annotated[UploadFile, File(description="PNG/JPEG/WebP image.")],
    k: Annotated[int, Form(ge=1, le=MAX_K)] = 10,
    sense: Annotated[str, Form(pattern=SENSE_PATTERN)] = "image",
    senses: Annotated[list[str] | None, Form()] = None,
    session: Annotated[str | None, Form(pattern=ID_PATTERN, max_length=MAX_ID_CHARS)] = None,
    after: Annotated[Seconds | None, Form(allow_inf_nan=False)] = None,
    before: Annotated[Seconds | None, Form(allow_inf_nan=False)] = None,
) -> SearchOut:
    if sense not in memory.senses and not memory.space.has_vision:
        raise CapabilityError(
            f"space {memory.space.name!r} has no vision, so this memory cannot search by image"
        )
    image = await run_in_threadpool(decode_image, await file.read())
    t0 = time.perf_counter()
    hits = await run_in_threadpool(
        lambda: memory.search_like(
            sense,
            image,
            k=k,
            senses=senses or None,
            session=session,
            after=after,
            before=before,
        )
    )
    response.headers["Server-Timing"] = f"library;dur={(time.perf_counter() - t0) * 1e3:.3f}"
    return SearchOut(hits=[HitOut.model_validate(h, from_attributes=True) for h in hits])
