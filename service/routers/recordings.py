"""Recordings out: ``GET /sessions/{session}/export.rrd`` (a Rerun recording of the session).

The library does the work (:func:`tactus_memory.recordings.export_rerun`): touch windows as
heat maps on the session timeline, notes as text logs, and with ``?q=`` the moments of that
query as annotations. The file is written to a temporary folder in the threadpool, sent,
then removed.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, BackgroundTasks, Query
from fastapi.responses import FileResponse

from tactus_memory.recordings.rerun import export_rerun
from tactus_memory.service.deps import MemoryDep, Read, SessionId
from tactus_memory.service.problems import ServiceUnavailable, problem_responses

router = APIRouter(prefix="/sessions", tags=["sessions"])

#: Rerun's own media type for .rrd files is not registered; the viewer opens the bytes
RRD_MEDIA_TYPE = "application/octet-stream"
MAX_QUERY_CHARS = 1000


@router.get(
    "/{session}/export.rrd",
    dependencies=[Read],
    summary="The session as a Rerun recording (.rrd)",
    response_class=FileResponse,
    responses={
        200: {"content": {RRD_MEDIA_TYPE: {}}, "description": "A Rerun .rrd file."},
        **problem_responses(404, 422, 503),
    },
)
def export_rrd(
    session: SessionId,
    memory: MemoryDep,
    background: BackgroundTasks,
    q: Annotated[
        str | None,
        Query(
            min_length=1,
            max_length=MAX_QUERY_CHARS,
            description="Annotate the moments of this query (natural language).",
        ),
    ] = None,
) -> FileResponse:
    try:
        import rerun  # noqa: F401
    except ImportError as exc:
        raise ServiceUnavailable(
            f"Rerun export needs rerun-sdk ({exc}): pip install 'tactus-memory[recordings]'"
        ) from exc
    folder = Path(tempfile.mkdtemp(prefix="tactus-rrd-"))
    try:
        out = folder / f"{session}.rrd"
        export_rerun(memory, session, out, query=q)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    background.add_task(shutil.rmtree, folder, ignore_errors=True)
    return FileResponse(out, media_type=RRD_MEDIA_TYPE, filename=out.name)
