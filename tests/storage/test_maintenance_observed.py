"""Background maintenance, observed (issue 16): with ``background=True`` the memory's own
maintenance thread builds the indexes past the (lowered) thresholds and compacts the small
fragments that single appends leave; no row is lost while writes go on."""

from __future__ import annotations

import numpy as np

from tactus_memory.memory.main import Memory
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.motion import MOTION_DIM, motion_memory


def _fragments(mem: Memory) -> int:
    return int(mem.store.items.stats()["fragment_stats"]["num_fragments"])


def test_background_thread_compacts_and_indexes(tmp_path) -> None:
    cfg = IndexConfig(threshold=240, scalar_threshold=120, rows_per_partition=60, compact_every=8)
    mem = motion_memory(tmp_path / "m", cfg, background=True)
    rng = np.random.default_rng(5)
    vecs = rng.standard_normal((300, MOTION_DIM)).astype(np.float32)
    # seven single-row appends: seven small fragments, below compact_every: nothing runs yet
    for i in range(7):
        mem.add("s1", "motion", vecs[i], t=float(i))
    mem.wait_for_maintenance(60)
    before = _fragments(mem)
    assert before >= 7, before
    assert not mem.store.has_vector_index()
    # the eighth append triggers the background thread: compaction merges the fragments
    mem.add("s1", "motion", vecs[7], t=7.0)
    assert mem._maintenance._thread is not None  # scheduled on the background thread
    mem.wait_for_maintenance(120)
    after = _fragments(mem)
    assert after < before, (before, after)
    assert len(mem) == 8
    # past the thresholds the background thread builds the scalar and the ANN indexes
    for k in range(8, 300, 20):
        chunk = vecs[k : k + 20]
        mem.add_many("s1", "motion", list(chunk), t=[float(k + j) for j in range(len(chunk))])
        mem.wait_for_maintenance(120)
    mem.add("s1", "motion", vecs[0] * 0.5, t=999.0)  # one more append: maintenance if due
    mem.wait_for_maintenance(120)
    assert mem.store.has_scalar_indexes() and mem.store.has_vector_index()
    assert len(mem) == 301
    hit = mem.search_vector(vecs[123], k=1, senses=["motion"])[0]
    assert hit.t == 123.0
