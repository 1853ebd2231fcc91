"""GET /health: liveness, the space, the live senses. Never needs a token."""

from __future__ import annotations

from fastapi import APIRouter

import tactus_memory
from tactus_memory.service.deps import StateDep
from tactus_memory.service.schemas import HealthOut

router = APIRouter(tags=["health"])


@router.get("/health", summary="Liveness and configuration", response_model=HealthOut)
def health(state: StateDep) -> HealthOut:
    memory = state.memory
    senses = sorted(memory.senses)
    return HealthOut(
        version=tactus_memory.__version__,
        space=memory.space.describe(),
        senses=senses,
        touch="touch" in senses,
        touch_unavailable=None if "touch" in senses else state.touch_unavailable,
    )
