"""``tactus search`` and ``tactus sessions``: query a memory from the shell.

The data directory is ``--data``, else ``$TACTUS_DATA``, else ``./memory``. The store's own
recorded space is used (MiniLM by default), so the query is embedded like the stored notes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail

if TYPE_CHECKING:
    from tactus_memory.memory import Memory

DATA_HELP = (
    "Memory location: a directory or s3:// gs:// az:// URI (default $TACTUS_DATA or ./memory)."
)


def _data_dir(data: str | None) -> str:
    return data or os.environ.get("TACTUS_DATA") or "./memory"


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
        _fail(f"no memory at {location!r} (set --data or TACTUS_DATA)")
    return Memory.open(location, space=space, space_path=space_path, space_dim=space_dim)


def _fail(message: str) -> None:
    fail(message)


def _print_json(value: Any) -> None:
    typer.echo(json.dumps(value, indent=2, ensure_ascii=False))


@app.command("search")
def search(
    query: str = typer.Argument(..., help="What to look for, in natural language."),
    data: str | None = typer.Option(None, "--data", help=DATA_HELP),
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
        _fail(str(exc))
        return
    if as_json:
        _print_json([h.model_dump() for h in hits])
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{len(hits)} hits for {query!r}")
    for col in ("score", "cosine", "sense", "session", "t", "id", "text"):
        table.add_column(col, overflow="fold")
    for h in hits:
        table.add_row(
            f"{h.score:.2f}",
            f"{h.cosine:.3f}",
            h.sense,
            h.session,
            f"{h.t:g}" if h.t == h.t_end else f"{h.t:g}-{h.t_end:g}",
            h.id,
            h.text or "",
        )
    Console().print(table)


@app.command("sessions")
def sessions(
    data: str | None = typer.Option(None, "--data", help=DATA_HELP),
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
        _fail(str(exc))
        return
    if as_json:
        _print_json([s.model_dump() for s in summaries])
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{len(summaries)} sessions")
    for col in ("session", "n", "per sense", "t_min", "t_max"):
        table.add_column(col)
    for s in summaries:
        per = ", ".join(f"{name}: {n}" for name, n in s.counts.items())
        table.add_row(s.id, str(s.n), per, f"{s.t_min:g}", f"{s.t_max:g}")
    Console().print(table)
