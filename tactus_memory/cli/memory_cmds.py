"""``tactus search``, ``tactus sessions`` and ``tactus reembed``: a memory from the shell.

The memory is ``--data``, else ``$TACTUS_DATA``, else ``./memory`` (the store ``make run``
serves), opened in its recorded space (MiniLM by default), so the query is embedded like the
stored notes; or, with ``--url``, a running ``tactus serve`` answers (no model loads here).
The questions (``last``, ``first``, ``count``, ``timeline``) are in
:mod:`tactus_memory.cli.ask_cmds`.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    AsJson,
    MemoryData,
    RayJob,
    Scope,
    Sort,
    Source,
    Windows,
)
from tactus_memory.cli.remote import get_json
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail
from tactus_memory.identity import DEFAULT_TENANT
from tactus_memory.signatures import grouped

if TYPE_CHECKING:
    from pydantic import BaseModel
    from rich.console import OverflowMethod

    from tactus_memory.memory.main import Memory

#: decimals of the times and scores printed in tables (JSON keeps every digit)
TIME_DECIMALS = 2


def _data_dir(data: str | None) -> str:
    """``--data``, else the settings' ``data`` (``$TACTUS_DATA``, a config file, ``./memory``)."""
    from tactus_memory.settings import Settings

    return data or Settings().data


def _open(
    data: str | None,
    space: str | None = None,
    space_path: str | None = None,
    space_dim: int | None = None,
    tenant: str = DEFAULT_TENANT,
    **open_kw: Any,
) -> Memory:
    """``tenant``'s memory in the store at ``data``, in its recorded space (the space options
    find its model); ``open_kw`` go to :meth:`Memory.open` (e.g. ``maintenance=``). A tenant
    that does not exist is an error (a typo never makes a tenant)."""
    from tactus_memory.memory.main import Memory
    from tactus_memory.storage.keys import KeyStore
    from tactus_memory.storage.tenants import tenant_exists

    location = _data_dir(data)
    if "://" not in location and not Path(location).is_dir():
        fail(f"no memory at {location!r} (set --data or TACTUS_DATA, or ask a server with --url)")
    if tenant != DEFAULT_TENANT and not tenant_exists(
        location, tenant, KeyStore(location).tenants()
    ):
        fail(f"no tenant {tenant!r} in {location} (its first key makes it: tactus keys create)")
    return Memory.open(
        location, space=space, space_path=space_path, space_dim=space_dim, tenant=tenant, **open_kw
    )


def one_source(data: str | None, url: str | None) -> None:
    """``--data`` and ``--url`` name two memories: refuse both at once."""
    if data and url:
        fail("give --data (open a store here) or --url (ask a running server), not both")


def fmt_t(t: float) -> str:
    """A time in seconds, rounded for reading (``6.666667`` -> ``6.67``)."""
    return f"{round(t, TIME_DECIMALS):g}"


def fmt_span(t: float, t_end: float) -> str:
    return fmt_t(t) if fmt_t(t) == fmt_t(t_end) else f"{fmt_t(t)}-{fmt_t(t_end)}"


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 session``, ``2 sessions``."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


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


def match_cell(score: float, match: bool, bar: float | None) -> str:
    """``yes`` / ``no`` against the sense's bar for this query (``-`` without one)."""
    if bar is None:
        return "-"
    return f"{'yes' if match else 'no'} ({bar:.2f})"


@app.command("search")
@grouped(scope=Scope, source=Source)
def search(
    query: str = typer.Argument(..., help="What to look for, in natural language."),
    k: int = typer.Option(10, "--k", min=1, max=1000, help="How many hits."),
    *,
    scope: Scope,
    as_json: AsJson = False,
    source: Source,
    windows: Windows = False,
    sort: Sort = None,
) -> None:
    """Search in plain language; each hit says whether it clears its sense's match bar; a
    touch hit is a grasp (its windows together) unless --windows.

    Scores are calibrated z-scores comparable across senses; a hit matches when its score
    reaches its sense's bar for this query, the rule of last/first/count."""
    from tactus_memory.errors import TactusError
    from tactus_memory.results import Hit

    one_source(source.data, source.url)
    from tactus_memory.search.grasps import windows_group

    group = windows_group(windows)
    if source.url:
        params = {"q": query, "k": k, "group": group, "sort": sort, **dataclasses.asdict(scope)}
        answer = get_json(source.url, "/search", params, source.token, source.tenant)
        hits = [Hit.model_validate(h) for h in answer["hits"]]
    else:
        try:
            memory = _open(source.data, *source.spaces, tenant=source.tenant)
            hits = memory.search(query, k=k, group=group, sort=sort, **scope.filters())
        except TactusError as exc:
            fail(str(exc))
    _print_results(
        hits,
        as_json=as_json,
        title=f"{plural(len(hits), 'hit')} for {query!r}",
        columns=("score", "match (bar)", "sense", "session", "t", "id", "text"),
        row=lambda h: (
            f"{h.score:.2f}",
            match_cell(h.score, h.match, h.bar),
            h.sense,
            h.session,
            fmt_span(h.t, h.t_end),
            h.id,
            h.text or "",
        ),
        overflow="fold",
    )


@app.command("sessions")
@grouped(source=Source)
def sessions(as_json: AsJson = False, *, source: Source) -> None:
    """List sessions: item counts per sense and time span."""
    from tactus_memory.errors import TactusError
    from tactus_memory.results import SessionSummary

    one_source(source.data, source.url)
    if source.url:
        answer = get_json(source.url, "/sessions", {}, source.token, source.tenant)
        summaries = [SessionSummary.model_validate(s) for s in answer["sessions"]]
    else:
        try:
            summaries = _open(source.data, *source.spaces, tenant=source.tenant).sessions()
        except TactusError as exc:
            fail(str(exc))
    _print_results(
        summaries,
        as_json=as_json,
        title=plural(len(summaries), "session"),
        columns=("session", "n", "per sense", "t_min", "t_max"),
        row=lambda s: (
            s.id,
            str(s.n),
            ", ".join(f"{name}: {n}" for name, n in s.counts.items()),
            fmt_t(s.t_min),
            fmt_t(s.t_max),
        ),
    )


@app.command("reembed")
@grouped(ray=RayJob)
def reembed(
    checkpoint: str = typer.Option(
        ..., "--checkpoint", help="the new touch checkpoint (.safetensors), or 'default'"
    ),
    data: MemoryData = None,
    sense: str = typer.Option("touch", "--sense", help="the touch sense to re-embed"),
    batch: int = typer.Option(256, "--batch", min=1, help="rows embedded and staged per commit"),
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
    *,
    ray: RayJob,
) -> None:
    """Recompute every stored vector of a touch sense with a new checkpoint, from the stored
    raw windows; swapped in one commit (readers see all old or all new vectors), resumable
    after a kill (rerun the same command). Rows without a raw window are listed. A bar on
    stderr shows the rows staged and the time left; the report is JSON on stdout. --ray: the
    embedding as a Ray Data job."""
    from tactus_memory.errors import TactusError

    try:
        from tactus_memory.adapters.touch import TactusEncoder

        memory = _open(data, space, space_path, space_dim)
        enc = TactusEncoder(None if checkpoint == "default" else checkpoint, name=sense)
        address = ray.cluster()
        if address is None:
            from tactus_memory.cli.progress import RowsBar

            with RowsBar(f"reembed {sense}") as bar:
                report = memory.reembed(sense, enc, batch=batch, on_rows=bar)
        else:
            from tactus_memory.recordings.ray_jobs import reembed_on_ray

            report = reembed_on_ray(memory, sense, enc, address=address, workers=ray.ray_workers,
                                    batch=batch)  # fmt: skip
    except (TactusError, FileNotFoundError, ValueError, ImportError) as exc:
        fail(str(exc))
        return
    _print_json(report.model_dump())


@app.command("teach")
@grouped(source=Source)
def teach(
    label: Annotated[str, typer.Argument(help="What was held, in words (e.g. drill).")],
    session: Annotated[str, typer.Option("--session", help="The session of the grasp.")],
    after: Annotated[float | None, typer.Option(help="Span start (s, session clock).")] = None,
    before: Annotated[float | None, typer.Option(help="Span end (s, session clock).")] = None,
    sense: Annotated[str, typer.Option(help="The sense whose windows were the grasp.")] = "touch",
    as_json: AsJson = False,
    *,
    source: Source,
) -> None:
    """Teach an object: the session's windows between --after and --before held LABEL.

    The label becomes a search target beside the encoder's classes (``tactus search "when was
    I holding the drill"`` then ranks touch by the label and the taught grasp)."""
    from tactus_memory.errors import TactusError

    one_source(source.data, source.url)
    try:
        if source.url:
            from tactus_memory.client.main import Client

            with Client(source.url, token=source.token, tenant=source.tenant) as client:
                got = client.teach(label, session=session, after=after, before=before, sense=sense)
        else:
            with _open(source.data, *source.spaces, tenant=source.tenant) as memory:
                got = memory.teach(label, session=session, after=after, before=before, sense=sense)
    except TactusError as exc:
        fail(str(exc))
    if as_json:
        _print_json(got.to_dict())
        return
    typer.echo(
        f"taught {got.label!r}: {plural(got.windows, 'window')} of {got.session} "
        f"({got.sense}) from {fmt_span(got.t, got.t_end)}; id {got.id}"
    )
