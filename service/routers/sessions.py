"""Sessions: list, summarise, delete."""

from __future__ import annotations

from fastapi import APIRouter

from tactus_memory.errors import NotFoundError
from tactus_memory.service.deps import Admin, MemoryDep, Read, SessionId
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import DeletedOut, SessionOut, SessionsOut

router = APIRouter(prefix="/sessions", tags=["sessions"])


def _out(summary: object) -> SessionOut:
    return SessionOut.model_validate(summary, from_attributes=True)


@router.get(
    "",
    dependencies=[Read],
    summary="List sessions with counts per sense",
    response_model=SessionsOut,
)
def list_sessions(memory: MemoryDep) -> SessionsOut:
    return SessionsOut(sessions=[_out(s) for s in memory.sessions()])


@router.get(
    "/{session}",
    dependencies=[Read],
    summary="One session: counts per sense and time span",
    response_model=SessionOut,
    responses=problem_responses(404, 422),
)
def get_session(session: SessionId, memory: MemoryDep) -> SessionOut:
    return _out(memory.session(session))


@router.delete(
    "/{session}",
    dependencies=[Admin],
    summary="Delete a session and everything keyed by it (items, clock offsets)",
    description="200 when anything was removed, whether or not the session held items (a "
    "session with only clock offsets is a session too); 404 when nothing was there.",
    response_model=DeletedOut,
    responses=problem_responses(404, 422),
)
def delete_session(session: SessionId, memory: MemoryDep) -> DeletedOut:
    offsets = len(memory.clock_offsets(session))
    deleted = memory.delete_session(session)  # its items and its clock offsets
    if not deleted and not offsets:
        raise NotFoundError(f"no session {session!r}")
    return DeletedOut(id=session, deleted=deleted, clock_offsets=offsets)
