"""``GET /retention``: the retention policy and what maintenance did (behind the token).

The policy is the maintenance policy's (:mod:`tactus_memory.storage.retention`); the counts
are this process's (a replica started with ``--no-maintain`` reports none: ``tactus
maintain`` prints its own).
"""

from __future__ import annotations

from fastapi import APIRouter

from tactus_memory.service.deps import MemoryDep
from tactus_memory.service.schemas import RetentionOut

router = APIRouter(tags=["health"])


@router.get(
    "/retention",
    summary="Retention: expiry and thinning policy, items removed, erasure pending",
    response_model=RetentionOut,
)
def retention(memory: MemoryDep) -> RetentionOut:
    store = memory.store
    cfg, report = store.maintenance, store.retention.report
    return RetentionOut(
        retain_days=cfg.retain_days,
        thin_after_days=cfg.thin_after_days,
        thin_cosine=cfg.thin_cosine,
        rules=len(cfg.retention),
        erase_deleted=cfg.erase_deleted,
        retain_seconds=cfg.retain_seconds,
        maintained_here=cfg.maintain,
        expired=report.expired_total,
        thinned=report.thinned_total,
        last_run=report.last_run,
        erasure_pending=store.erasure.pending(),
    )
