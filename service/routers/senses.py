"""Senses: list them (with provenance), register a VectorSense over HTTP."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.service.deps import Admin, MemoryDep, Read
from tactus_memory.service.problems import problem_responses
from tactus_memory.service.schemas import SenseIn, SenseOut, SensesOut

router = APIRouter(prefix="/senses", tags=["senses"])


def _senses(memory: Any) -> list[SenseOut]:
    return [SenseOut.model_validate(s, from_attributes=True) for s in memory.sense_info()]


@router.get(
    "",
    dependencies=[Read],
    summary="Registered senses with provenance and row counts",
    response_model=SensesOut,
)
def list_senses(memory: MemoryDep) -> SensesOut:
    return SensesOut(senses=_senses(memory))


@router.post(
    "",
    dependencies=[Admin],
    status_code=201,
    summary="Register a vector sense (precomputed embeddings, e.g. motion)",
    description=(
        "Adds a `VectorSense`: items of this sense are vectors computed by an encoder outside "
        "the memory (e.g. an IMU motion model that targets this memory's space). `dim` must "
        "equal the space's dimension. Store vectors with `POST /sessions/{id}/vectors`."
    ),
    response_model=SenseOut,
    responses=problem_responses(409, 422),
)
def add_sense(body: SenseIn, memory: MemoryDep) -> SenseOut:
    described = body.model_dump(include={"space", "encoder", "version", "checkpoint_sha256"})
    sense = VectorSense(body.name, body.dim, **described)
    memory.add_sense(sense)
    return next(s for s in _senses(memory) if s.name == body.name)
