"""``GET /retention``: the retention policy and what maintenance did (behind the token).

The policy is the maintenance policy's (:mod:`tactus_memory.storage.retention`); the counts
are this process's (a replica started with ``--no-maintain`` reports none: ``tactus
maintain`` prints its own; of ``--workers N``, worker 0 maintains and says which it is).
"""

from __future__ import annotations

from dataclasses import asdict

from fastapi import APIRouter

from tactus_memory.service.deps import MemoryDep, Read, StateDep
from tactus_memory.service.schemas import MaintenancePassOut, RetentionOut
from tactus_memory.storage.retention import POLICY_FIELDS

router = APIRouter(tags=["health"])

#: the policy fields reported as they are
POLICY = {*POLICY_FIELDS, "erase_deleted", "retain_seconds"}


@router.get(
    "/retention",
    dependencies=[Read],
    summary="Retention: expiry and thinning policy, items removed, erasure pending",
    response_model=RetentionOut,
)
def retention(memory: MemoryDep, state: StateDep) -> RetentionOut:
    store = memory.store
    cfg = store.maintenance
    policy = cfg.model_dump(include=POLICY)
    return RetentionOut(
        **policy, **asdict(store.retention.report), rules=len(cfg.retention),
        maintained_here=cfg.maintain,
        worker=None if state.workers is None else state.workers.index,
        erasure_pending=store.erasure.pending() if cfg.maintain else None,
        passes=[MaintenancePassOut(**asdict(p)) for p in list(store.passes)],
    )  # fmt: skip
