"""A time window is narrowed by the store's longest item (``t >= after - longest``, which the
``t`` index answers): the longest item is read from the fragments written since it was last
read, grows with appends, stays an upper bound after deletes, and a window still finds every
item that overlaps it. Real LanceDB files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.storage.spans import Spans
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Where

DIM = 384


def test_narrowed_adds_the_bound_only_with_a_lower_time_bound() -> None:
    w = Where().session("s").overlaps(100.0, 200.0)
    narrowed = w.narrowed(30.0)
    assert narrowed.parts == [*w.parts, "t >= 70.0"]
    assert w.parts != narrowed.parts  # a copy: the original keeps its conditions
    assert Where().overlaps(None, 200.0).narrowed(30.0).parts == ["t <= 200.0"]
    with pytest.raises(InvalidInputError, match="longest"):
        w.narrowed(float("nan"))


def test_the_longest_item_follows_appends_and_windows_find_long_items(tmp_path: Path) -> None:
    mem = Memory.open(str(tmp_path / "m"), space="minilm-l6", background=False)
    mem.add_sense(VectorSense("v", dim=DIM))
    rng = np.random.default_rng(0)
    mem.add_many("s", "v", list(as_unit_rows(rng.standard_normal((50, DIM)))), t=list(range(50)))
    spans = Spans()
    items = mem.store.items
    assert spans.longest(items) == 0.0  # points only
    long_vec = as_unit_rows(rng.standard_normal(DIM))[0]
    (long_id,) = mem.add_many("s", "v", [long_vec], t=[5.0], t_end=[905.0])
    assert spans.longest(items) == 900.0
    mem.add_many("s", "v", [long_vec], t=[60.0], t_end=[70.0])  # shorter: no change
    assert spans.longest(items) == 900.0

    # a window long after every point but inside the long item finds it, and only it
    hits = mem.search_vector(long_vec, k=5, after=800.0, before=850.0)
    assert [h.id for h in hits] == [long_id]
    # a window at the start of the long item finds the points in it and the long item
    hits = mem.search_vector(long_vec, k=20, after=10.0, before=12.0)
    assert {h.t for h in hits} == {5.0, 10.0, 11.0, 12.0}

    mem.delete(long_id)
    assert spans.longest(items) == 900.0  # an upper bound: still correct, less narrow
    assert mem.search_vector(long_vec, k=5, after=800.0, before=850.0) == []
