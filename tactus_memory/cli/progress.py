"""Progress with the time left, for the CLI's long jobs (``tactus reembed``, ``tactus maintain
--sense-codes`` and ``--facets``; ``tactus ingest``, ``pretrain`` and ``train`` draw tqdm's bar
themselves): a tqdm bar on stderr, ``done/total [elapsed<remaining, rate]``, so stdout keeps
only the job's JSON report.

The library calls back with how far it got (``on_batch(rows)`` for the store's rewrites,
``on_rows(done, total)`` for a re-embedding); :class:`RowsBar` turns those into the bar.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any


class RowsBar:
    """A tqdm bar of ``total`` rows named ``desc`` on stderr; call it with the rows done so
    far (``bar(rows)``), or with ``(rows, total)`` when the total is known only later (a
    resumed re-embedding). A context manager: the bar is closed (its last line printed) on
    exit."""

    def __init__(self, desc: str, total: int | None = None, unit: str = "row") -> None:
        from tqdm.auto import tqdm

        # file: the stderr of the moment (a test's CliRunner swaps it in)
        self.bar: Any = tqdm(
            total=total,
            desc=desc,
            unit=unit,
            unit_scale=True,
            dynamic_ncols=True,
            file=sys.stderr,
        )

    def __call__(self, rows: int, total: int | None = None) -> None:
        if total is not None and total != self.bar.total:
            self.bar.total = total
        self.bar.update(rows - self.bar.n)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> RowsBar:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
