"""Objects you teach (:mod:`tactus_memory.search.teaching`): ``POST /sessions/{id}/labels``
marks a span as "holding <label>", ``GET /labels`` lists the teachings, ``DELETE
/labels/{id}`` forgets one. ``GET /senses`` lists each sense's taught labels."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query
from starlette.concurrency import run_in_threadpool

from tactus_memory.errors import NotFoundError
from tactus_memory.limits import SENSE_NAME_PATTERN
from tactus_memory.service.deps import Admin, MemoryDep, Read, SessionId, Write
from tactus_memory.service.label_schemas import ForgottenOut, LabelIn, TaughtListOut, TaughtOut
from tactus_memory.service.problems import problem_responses

router = APIRouter(tags=["labels"])


@router.post(
    "/sessions/{session}/labels",
    dependencies=[Write],
    status_code=201,
    summary="Teach an object: this span was a grasp of <label>",
    description=(
        "The session's windows of `sense` overlapping `[t, t_end]` are marked as holding "
        "`label`. The label becomes a search target beside the sense's trained classes: a "
        "text query nearest to it ranks touch by the label's text target plus the mean "
        "embedding of the taught windows. 404 when no window of the sense overlaps the span."
    ),
    response_model=TaughtOut,
    responses=problem_responses(404, 422),
)
async def teach(session: SessionId, body: LabelIn, memory: MemoryDep) -> TaughtOut:
    got = await run_in_threadpool(
        lambda: memory.teach(
            body.label, session=session, after=body.t, before=body.t_end, sense=body.sense
        )
    )
    return TaughtOut(**got.to_dict())


@router.get(
    "/labels",
    dependencies=[Read],
    summary="The objects taught to this memory",
    response_model=TaughtListOut,
    responses=problem_responses(422),
)
def list_labels(
    memory: MemoryDep,
    sense: Annotated[
        str | None, Query(pattern=SENSE_NAME_PATTERN, description="Only this sense.")
    ] = None,
) -> TaughtListOut:
    return TaughtListOut(labels=[TaughtOut(**t.to_dict()) for t in memory.taught(sense)])


@router.delete(
    "/labels/{teaching}",
    dependencies=[Admin],
    summary="Forget one teaching",
    response_model=ForgottenOut,
    responses=problem_responses(404, 422),
)
def forget_label(
    memory: MemoryDep,
    teaching: Annotated[str, Path(pattern="^[0-9a-f]{32}$", description="The teaching's id.")],
) -> ForgottenOut:
    n = memory.forget(id=teaching)
    if not n:
        raise NotFoundError(f"no teaching {teaching!r}")
    return ForgottenOut(deleted=n)
