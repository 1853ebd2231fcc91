"""Writes of text, images and precomputed vectors into a session.

The write path (every write route, touch and the WebSocket stream included): the edge parses
the body and checks shapes and sizes (``schemas.py``, ``arrays.py``), then makes ONE library
call, ``GroupCommitter.submit`` (``deps.ServiceState.write``): the sense validates the items
(a bad item fails its own request at once) and the write is queued; writes of every session
that arrive within one tick are embedded in one call per sense and stored in ONE LanceDB
commit; the 201 is sent only after that commit returned, so an acknowledged write survives a
crash of the server. A full queue answers 503 with ``Retry-After``.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile

from tactus_memory.errors import CapabilityError, InvalidInputError
from tactus_memory.limits import ID_PATTERN
from tactus_memory.service.arrays import loads_strict
from tactus_memory.service.deps import (
    MemoryDep,
    SessionId,
    StateDep,
    TenantDep,
    WriteThreadsDep,
)
from tactus_memory.service.images import decode_image
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import StoredOut, TextIn, VectorsIn
from tactus_memory.times import Seconds

router = APIRouter(prefix="/sessions/{session}", tags=["items"])


@router.post(
    "/text",
    status_code=201,
    summary="Store a note or caption",
    response_model=StoredOut,
    responses=problem_responses(404, 413, 422),
)
async def add_text(
    session: SessionId, body: TextIn, state: StateDep, tenant: TenantDep
) -> StoredOut:
    ids = await state.write(
        tenant,
        session,
        "text",
        [body.text],
        t=[body.t],
        t_end=[body.t_end],
        meta=[body.meta],
        ids=None if body.id is None else [body.id],
        position=None if body.position is None else [body.position],
        frame=body.frame,
    )
    return StoredOut(ids=ids, count=1)


@router.post(
    "/vectors",
    status_code=201,
    summary="Store precomputed vectors of a registered sense",
    description="For senses whose encoder runs elsewhere (register one with `POST /senses`). "
    "Each vector must have the space's dimension; it is stored normalised.",
    response_model=StoredOut,
    responses=problem_responses(404, 413, 422),
)
async def add_vectors(
    session: SessionId, body: VectorsIn, state: StateDep, tenant: TenantDep
) -> StoredOut:
    n = len(body.vectors)
    if len(body.t) != n:
        raise InvalidInputError(f"t has {len(body.t)} entries for {n} vectors")
    ids = await state.write(
        tenant,
        session,
        body.sense,
        body.vectors,
        t=body.t,
        t_end=body.t_end,
        meta=body.meta,
        ids=body.ids,
    )
    return StoredOut(ids=ids, count=len(ids))


@router.post(
    "/image",
    status_code=201,
    summary="Store a camera image (spaces with vision only)",
    description="Multipart upload (`file`: PNG/JPEG/WebP, at most 64 M pixels, sides >= 8 px; "
    "`t`, optional `t_end`, `meta` as a JSON string). The item keeps a 256 px thumbnail, "
    "drawn by `GET /items/{id}/image.png`. "
    "Answers 400 when the memory's space has no vision (e.g. the default MiniLM space).",
    response_model=StoredOut,
    responses=problem_responses(400, 404, 413, 422),
)
async def add_image(
    session: SessionId,
    memory: MemoryDep,
    threads: WriteThreadsDep,
    state: StateDep,
    tenant: TenantDep,
    file: Annotated[UploadFile, File(description="PNG/JPEG/... image.")],
    t: Annotated[Seconds, Form(allow_inf_nan=False)],
    t_end: Annotated[Seconds | None, Form(allow_inf_nan=False)] = None,
    meta: Annotated[str | None, Form(description="JSON object.", max_length=65536)] = None,
    id: Annotated[str | None, Form(pattern=ID_PATTERN)] = None,  # noqa: A002
) -> StoredOut:
    if "image" not in memory.senses and not memory.space.has_vision:
        raise CapabilityError(
            f"space {memory.space.name!r} has no vision, so this memory cannot store images; "
            "open the memory with a vision space such as Qwen3VLSpace"
        )
    meta_obj = None
    if meta is not None:
        meta_obj = loads_strict(meta)
        if not isinstance(meta_obj, dict):
            raise InvalidInputError("meta must be a JSON object")
    image = await threads.run(decode_image, await file.read())
    ids = await state.write(
        tenant,
        session,
        "image",
        [image],
        t=[t],
        t_end=[t_end],
        meta=[meta_obj],
        ids=None if id is None else [id],
    )
    return StoredOut(ids=ids, count=1)
