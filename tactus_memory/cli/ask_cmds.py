"""``tactus last | first | count | timeline``: the memory's "when" questions from the shell.

The same options as ``tactus search`` (``--sense``, ``--session``, ``--after``, ``--before``,
``--json``, ``--data`` or ``--url``): locally through ``Memory.last`` / ``first`` /
``occurrences`` / ``timeline``, or over HTTP through ``/last``, ``/first``, ``/count`` and
``/sessions/{id}/timeline`` of a running server. A match is a hit that clears its sense's bar
(:mod:`tactus_memory.search.matching`); matches within ``merge_gap`` seconds are one occurrence.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    After,
    AsJson,
    Before,
    MemoryData,
    Senses,
    ServerToken,
    ServerUrl,
    Session,
    Tenant,
)
from tactus_memory.cli.memory_cmds import (
    _open,
    _print_json,
    _print_results,
    fmt_span,
    match_cell,
    one_source,
    plural,
)
from tactus_memory.cli.remote import get_json, session_path
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail
from tactus_memory.storage.tenants import DEFAULT_TENANT

if TYPE_CHECKING:
    from tactus_memory.results import Moment, Occurrences

Query = typer.Argument(..., help="What happened, in natural language.")


def _occurrences(
    query: str,
    sense: list[str] | None,
    session: str | None,
    after: float | None,
    before: float | None,
    where: tuple[str | None, str | None, str | None, str],
    space: tuple[str | None, str | None, int | None],
) -> Occurrences:
    """Every occurrence of ``query`` in scope, from the store (``--data``) or a server."""
    from tactus_memory.errors import TactusError
    from tactus_memory.results import Occurrences

    data, url, token, tenant = where
    one_source(data, url)
    if url:
        params = {"q": query, "sense": sense, "session": session, "after": after}
        answer = get_json(url, "/count", {**params, "before": before}, token, tenant)
        return Occurrences.model_validate(answer)
    try:
        memory = _open(data, *space, tenant=tenant)
        if session is not None:
            memory.session(session)  # an unknown session is an error, as over HTTP
        return memory.occurrences(
            query, senses=sense or None, session=session, after=after, before=before
        )
    except TactusError as exc:
        fail(str(exc))


def _print_moment(query: str, which: str, moment: Moment | None, as_json: bool) -> None:
    if as_json:
        _print_json(None if moment is None else moment.model_dump())
        return
    if moment is None:
        typer.echo(f"nothing matches {query!r}")
        return
    typer.echo(
        f"{which} {query!r}: session {moment.session}, t {fmt_span(moment.t, moment.t_end)} s, "
        f"senses {', '.join(moment.senses)}, score {moment.score:.2f}"
    )
    _print_results(
        moment.hits,
        as_json=False,
        title=f"its evidence ({plural(len(moment.hits), 'item')})",
        columns=("t", "sense", "score", "match (bar)", "id", "text"),
        row=lambda e: (
            fmt_span(e.t_aligned, e.t_end_aligned),
            e.sense,
            f"{e.score:.2f}",
            match_cell(e.score, e.match, e.bar),
            e.id,
            e.text or "",
        ),
        overflow="fold",
    )


def _ask(which: str, query: str, options: dict[str, Any]) -> None:
    as_json = options.pop("as_json")
    found = _occurrences(query, **options)
    moment = None
    if found.moments:
        moment = found.moments[-1] if which == "last" else found.moments[0]
    _print_moment(query, which, moment, as_json)


@app.command("last")
def last(
    query: str = Query,
    sense: Senses = None,
    session: Session = None,
    after: After = None,
    before: Before = None,
    as_json: AsJson = False,
    data: MemoryData = None,
    tenant: Tenant = DEFAULT_TENANT,
    url: ServerUrl = None,
    token: ServerToken = None,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """When did it last happen? The latest occurrence and its evidence across senses."""
    where, spc = (data, url, token, tenant), (space, space_path, space_dim)
    opts = {"sense": sense, "session": session, "after": after, "before": before}
    _ask("last", query, {**opts, "where": where, "space": spc, "as_json": as_json})


@app.command("first")
def first(
    query: str = Query,
    sense: Senses = None,
    session: Session = None,
    after: After = None,
    before: Before = None,
    as_json: AsJson = False,
    data: MemoryData = None,
    tenant: Tenant = DEFAULT_TENANT,
    url: ServerUrl = None,
    token: ServerToken = None,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """When did it first happen? The earliest occurrence and its evidence across senses."""
    where, spc = (data, url, token, tenant), (space, space_path, space_dim)
    opts = {"sense": sense, "session": session, "after": after, "before": before}
    _ask("first", query, {**opts, "where": where, "space": spc, "as_json": as_json})


@app.command("count")
def count(
    query: str = Query,
    sense: Senses = None,
    session: Session = None,
    after: After = None,
    before: Before = None,
    as_json: AsJson = False,
    data: MemoryData = None,
    tenant: Tenant = DEFAULT_TENANT,
    url: ServerUrl = None,
    token: ServerToken = None,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """How many distinct times did it happen? Each occurrence with its time and senses."""
    where, spc = (data, url, token, tenant), (space, space_path, space_dim)
    found = _occurrences(query, sense, session, after, before, where, spc)
    if as_json:
        _print_json(found.model_dump())
        return
    bound = " (at least: narrow with --after/--before)" if found.capped else ""
    _print_results(
        found.moments,
        as_json=False,
        title=f"{plural(found.count, 'occurrence')} of {query!r}{bound}",
        columns=("session", "t", "senses", "score"),
        row=lambda m: (m.session, fmt_span(m.t, m.t_end), ", ".join(m.senses), f"{m.score:.2f}"),
    )


@app.command("timeline")
def timeline(
    session: str = typer.Argument(..., help="The session to lay out in time order."),
    sense: Senses = None,
    after: After = None,
    before: Before = None,
    episodes: bool = typer.Option(
        False, "--episodes", help="Episodes (coherent stretches of one stream), not items."
    ),
    limit: int | None = typer.Option(None, "--limit", min=1, help="Only the first LIMIT."),
    as_json: AsJson = False,
    data: MemoryData = None,
    tenant: Tenant = DEFAULT_TENANT,
    url: ServerUrl = None,
    token: ServerToken = None,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """A session in time order: its items, or its episodes, on the session clock.

    A read: episodes not yet stored are computed for the answer, not written."""
    from tactus_memory.errors import TactusError
    from tactus_memory.results import TimelineItem
    from tactus_memory.temporal.episodes import Episode

    one_source(data, url)
    if url:
        params = {"sense": sense, "after": after, "before": before, "limit": limit}
        path = session_path(session, "/timeline")
        params["episodes"] = str(episodes).lower()
        answer = get_json(url, path, params, token, tenant)
        rows: list[Any] = [
            (Episode if episodes else TimelineItem).model_validate(r)
            for r in answer["episodes" if episodes else "items"]
        ]
    else:
        try:
            memory = _open(data, space, space_path, space_dim, tenant=tenant)
            rows = memory.timeline(session, sense or None, after, before, episodes, limit=limit)
        except TactusError as exc:
            fail(str(exc))
    if episodes:
        _print_results(
            rows,
            as_json=as_json,
            title=f"session {session}: {plural(len(rows), 'episode')}",
            columns=("t", "sense", "source", "episode", "items", "representative"),
            row=lambda e: (
                fmt_span(e.t_aligned, e.t_end_aligned),
                e.sense,
                e.source,
                str(e.episode),
                str(e.n),
                e.representative,
            ),
        )
        return
    _print_results(
        rows,
        as_json=as_json,
        title=f"session {session}: {plural(len(rows), 'item')}",
        columns=("t", "sense", "source", "id", "text"),
        row=lambda it: (
            fmt_span(it.t_aligned, it.t_end_aligned),
            it.sense,
            it.source,
            it.id,
            it.text or "",
        ),
        overflow="fold",
    )
