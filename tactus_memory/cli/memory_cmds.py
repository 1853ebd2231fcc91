"""``tactus search`` and ``tactus sessions``: query a memory from the shell.

The data directory is ``--data``, else ``$TACTUS_DATA``, else ``./memory``. The store's own
recorded space is used (MiniLM by default), so the query is embedded like the stored notes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import MemoryData
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail
from tactus_memory.connect import DEFAULT_MEMORY, ENV_MEMORY

if TYPE_CHECKING:
    from pydantic import BaseModel
    from rich.console import OverflowMethod

    from tactus_memory.memory import Memory


def _data_dir(data: str | None) -> str:
    return data or os.environ.get(ENV_MEMORY) or DEFAULT_MEMORY


def _open(
    data: str | None,
    space: str | None = None,
    space_path: str | None = None,
    space_dim: int | None = None,
) -> Memory:
    """The memory at ``data`` in its recorded space (the space options find its model)."""
    from tactus_memory.memory import Memory

    location = _data_dir(data)
    if "://" not in location and not Path(location).is_dir():
        fail(f"no memory at {location!r} (set --data or TACTUS_DATA)")
    return Memory.open(location, space=space, space_path=space_path, space_dim=space_dim)


def _print_json(value: Any) -> None:
    typer.echo(json.dumps(value, indent=2, ensure_ascii=False))


def _print_results(
    results: Sequence[BaseModel],
    *,
    as_json: bool,
    title: str,
    columns: Sequence[str],
    row: Callable[[Any], Sequence[str]],
    overflow: OverflowMethod = "ellipsis",
) -> None:
    """``results`` as a JSON list (``--json``), else as a rich table: ``columns``, and
    ``row(result)`` for each result."""
    if as_json:
        _print_json([r.model_dump() for r in results])
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    for col in columns:
        table.add_column(col, overflow=overflow)
    for r in results:
        table.add_row(*row(r))
    Console().print(table)


@app.command("search")
def search(
    query: str = typer.Argument(..., help="What to look for, in natural language."),
    data: MemoryData = None,
    k: int = typer.Option(10, "--k", min=1, max=1000, help="How many hits."),
    sense: list[str] | None = typer.Option(
        None, "--sense", help="Only these senses (repeatable); default all with rows."
    ),
    session: str | None = typer.Option(None, "--session", help="Only this session."),
    after: float | None = typer.Option(None, "--after", help="Items overlapping t >= AFTER."),
    before: float | None = typer.Option(None, "--before", help="Items overlapping t <= BEFORE."),
    as_json: bool = typer.Option(False, "--json", help="Print a JSON list of hits."),
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """Search the memory; scores are calibrated z-scores comparable across senses."""
    from tactus_memory.errors import TactusError

    try:
        memory = _open(data, space, space_path, space_dim)
        hits = memory.search(
            query, k=k, senses=sense or None, session=session, after=after, before=before
        )
    except TactusError as exc:
        fail(str(exc))
        return
    _print_results(
        hits,
        as_json=as_json,
        title=f"{len(hits)} hits for {query!r}",
        columns=("score", "cosine", "sense", "session", "t", "id", "text"),
        row=lambda h: (
            f"{h.score:.2f}",
            f"{h.cosine:.3f}",
            h.sense,
            h.session,
            f"{h.t:g}" if h.t == h.t_end else f"{h.t:g}-{h.t_end:g}",
            h.id,
            h.text or "",
        ),
        overflow="fold",
    )


@app.command("sessions")
def sessions(
    data: MemoryData = None,
    as_json: bool = typer.Option(False, "--json", help="Print a JSON list of sessions."),
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """List sessions: item counts per sense and time span."""
    from tactus_memory.errors import TactusError

    try:
        summaries = _open(data, space, space_path, space_dim).sessions()
    except TactusError as exc:
        fail(str(exc))
        return
    _print_results(
        summaries,
        as_json=as_json,
        title=f"{len(summaries)} sessions",
        columns=("session", "n", "per sense", "t_min", "t_max"),
        row=lambda s: (
            s.id,
            str(s.n),
            ", ".join(f"{name}: {n}" for name, n in s.counts.items()),
            f"{s.t_min:g}",
            f"{s.t_max:g}",
        ),
    )
