"""A search whose senses compare different query vectors (text as it is, touch through its
query transform) asks their ANN queries at once (``Ranker.parallel_groups``): the hits are
those of asking one after the other, and the session scope of the caller (a key's
``--sessions`` prefix, a context variable) holds in the threads that ask. Real MiniLM, the
shipped touch encoder, real LanceDB files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.memory.main import Memory
from tactus_memory.search.ranking import Ranker
from tactus_memory.where import sessions_under


@pytest.fixture
def mem(tmp_path: Path, minilm_space) -> Memory:
    mem = Memory.open(str(tmp_path / "m"), space=minilm_space, background=False)
    mem.add_sense(TactusEncoder())
    rng = np.random.default_rng(5)
    for session in ("lab-1", "home-1"):
        notes = [f"{session}: holding a red mug", f"{session}: the drill on the bench"]
        mem.add_many(session, "text", notes, t=[1.0, 2.0])
        windows = np.full((6, 8, 32, 32), 512, np.int16)
        windows[:, :, 8:24, 6:20] += rng.integers(100, 300, (6, 8, 16, 14)).astype(np.int16)
        mem.add_many(session, "touch", list(windows), t=[float(i) for i in range(6)])
    return mem


def hits(mem: Memory, q: str, parallel: bool) -> list[tuple[str, float]]:
    Ranker.parallel_groups = parallel
    try:
        return [(h.id, round(h.score, 6)) for h in mem.search(q, k=8)]
    finally:
        Ranker.parallel_groups = True


def test_parallel_groups_give_the_hits_of_one_after_the_other(mem: Memory) -> None:
    # queries that reach no touch caption (issue 50: "squeezing something soft" still reaches
    # the firm windows' "..., squeezing hard" above the gate chosen for precision and ranks
    # every window of this store above the notes; benchmarks/results/caption_gate.json has it
    # among the held-out wrong pairs: "squeezing hard, a firm grasp" at cosine 0.82)
    for q in ("holding a red mug", "pressing a sponge", "a drill"):
        together = hits(mem, q, True)
        assert {mem.get_item(i).sense for i, _ in together} == {"text", "touch"}
        assert together == hits(mem, q, False)


def test_the_session_scope_holds_in_the_threads_that_ask(mem: Memory) -> None:
    with sessions_under("lab-"):
        found = mem.search("holding a red mug", k=12)
    assert {h.session for h in found} == {"lab-1"}
    assert {h.sense for h in found} == {"text", "touch"}
