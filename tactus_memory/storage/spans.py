"""The longest item of a store (``t_end - t``), kept up to date by reading only the
fragments written since it was last read, so that a time window's overlap condition can be
narrowed to what the ``t`` index answers.

Why: an item overlaps ``[after, before]`` when ``t_end >= after AND t <= before``. No index
answers ``t_end >= after`` cheaply (a BTREE on ``t_end`` intersected with ``t``'s costs more
than the scan), so LanceDB reads ``t_end`` of every row that started before ``before``:
at 1M rows a day's window cost 550 ms as an exact scan of one sense
(benchmarks/search_1m.py). Every overlapping item also started at or after
``after - longest``, a bound the ``t`` index answers, which leaves ``t_end`` to be read
only for the rows in that range.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np


class Spans:
    """The longest ``t_end - t`` of one items table (an upper bound: deleted rows keep it)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        #: the table version and the highest fragment id read so far
        self._version: int | None = None
        self._fragment = -1
        self._longest = 0.0

    def longest(self, items: Any) -> float:
        """Seconds: the longest item of ``items`` (a LanceDB table) in its current version.
        Appends, upserts and compaction write fragments with new, higher ids: only those
        are read."""
        with self._lock:
            version = items.version
            if version == self._version:
                return self._longest
            ds = items.to_lance()
            new = [f for f in ds.get_fragments() if f.fragment_id > self._fragment]
            if new:
                tbl = ds.scanner(columns=["t", "t_end"], fragments=new).to_table()
                if tbl.num_rows:
                    t = tbl.column("t").to_numpy()
                    t_end = tbl.column("t_end").to_numpy()
                    self._longest = max(self._longest, float(np.max(t_end - t)))
                self._fragment = max(f.fragment_id for f in new)
            self._version = version
            return self._longest
