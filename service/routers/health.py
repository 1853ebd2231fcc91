"""Probes, never behind the token:

* ``GET /live``: liveness. The process and its event loop answer; touches nothing else.
* ``GET /health``: the store is readable (manifests and one row, see
  :mod:`tactus_memory.service.readiness`; the ``keys`` and ``audit`` tables and each opened
  tenant's folder too) plus the configuration (space, senses, touch); 503 problem naming
  the reason (the table, the tenant) when the store cannot be read.
* ``GET /ready``: readiness for traffic: the store is readable and the text model is loaded;
  503 with the reason otherwise: while ``tactus serve`` loads its models (the socket opens
  first), ``starting: [2/3] loading the text model (...)``, then the touch encoder's step;
  with ``--workers N``, until every worker is ready (``starting: worker 1 of 2 ...``).
  ``/health`` answers the same 503 until then (its configuration is not final).
"""

from __future__ import annotations

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

import tactus_memory
from tactus_memory.service.deps import Open, StateDep
from tactus_memory.service.problems import ServiceUnavailable, problem_responses
from tactus_memory.service.readiness import no_paths, service_problem
from tactus_memory.service.schemas import HealthOut, LiveOut, ReadyOut

router = APIRouter(tags=["health"])


@router.get(
    "/live", dependencies=[Open], summary="Liveness: the process answers", response_model=LiveOut
)
async def live() -> LiveOut:
    return LiveOut()


@router.get(
    "/health",
    dependencies=[Open],
    summary="Health: the store is readable, and the configuration",
    responses=problem_responses(503),
)
async def health(state: StateDep) -> HealthOut:
    if state.starting is not None:  # the configuration (senses) is not final yet
        raise ServiceUnavailable(f"starting: {state.starting}", retry_after=1)
    memory = state.memory
    why = await run_in_threadpool(service_problem, state)
    if why is not None:
        raise ServiceUnavailable(why)
    senses = sorted(memory.senses)
    why_touch = state.touch_unavailable
    return HealthOut(
        version=tactus_memory.__version__,
        space={k: v for k, v in memory.space.describe().items() if k != "path"},  # no paths
        senses=senses,
        touch="touch" in senses,
        touch_unavailable=None if "touch" in senses or not why_touch else no_paths(why_touch),
        read_only=state.read_only,
    )


@router.get(
    "/ready",
    dependencies=[Open],
    summary="Readiness: the store is readable and the text model is loaded",
    response_model=ReadyOut,
    responses=problem_responses(503),
)
async def ready(state: StateDep) -> ReadyOut:
    if state.starting is not None:
        raise ServiceUnavailable(f"starting: {state.starting}", retry_after=1)
    if not state.warm:
        raise ServiceUnavailable("starting: the text model is still loading", retry_after=1)
    waiting = state.workers.not_ready() if state.workers is not None else []
    if waiting:  # another worker of the group is loading (or being replaced)
        names = ", ".join(map(str, waiting))
        raise ServiceUnavailable(
            f"starting: worker {names} of {state.workers.count} is not ready", retry_after=1
        )
    why = await run_in_threadpool(service_problem, state)
    if why is not None:
        raise ServiceUnavailable(why)
    return ReadyOut(read_only=state.read_only)
