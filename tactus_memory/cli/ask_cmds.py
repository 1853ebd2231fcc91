"""``tactus last | first | count | timeline``: the memory's "when" questions from the shell.

The same options as ``tactus search`` (``--sense``, ``--session``, ``--after``, ``--before``,
``--json``, ``--data`` or ``--url``): locally through ``Memory.last`` / ``first`` /
``occurrences`` / ``timeline``, or over HTTP through ``/last``, ``/first``, ``/count`` and
``/sessions/{id}/timeline`` of a running server. A match is a hit that clears its sense's bar
(:mod:`tactus_memory.matching`); matches within ``merge_gap`` seconds are one occurrence.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import AsJson, Scope, Sort, Source, Window, Windows
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
from tactus_memory.cli.space_opts import fail
from tactus_memory.signatures import grouped

if TYPE_CHECKING:
    from tactus_memory.results import Occurrences

Query = typer.Argument(..., help="What happened, in natural language.")


Threshold = Annotated[
    float | None,
    typer.Option(
        "--threshold",
        help="Match bar on the calibrated score for every sense (default: per sense); a low "
        "bar (e.g. -10) lets every grasp scoring at least 0.4 x the best one match.",
    ),
]


def _occurrences(
    query: str,
    scope: Scope,
    source: Source,
    windows: bool = False,
    sort: str | None = None,
    threshold: float | None = None,
) -> Occurrences:
    """Every occurrence of ``query`` in scope, from the store (``--data``) or a server;
    touch asked of grasps unless ``windows``; in time order, or ``sort`` order; matched at
    the sense's bar, or ``threshold``."""
    from tactus_memory.search.grasps import windows_group

    group = windows_group(windows)
    from tactus_memory.errors import TactusError
    from tactus_memory.results import Occurrences

    one_source(source.data, source.url)
    if source.url:
        params = {"q": query, "group": group, "sort": sort, "threshold": threshold}
        params.update(dataclasses.asdict(scope))
        return Occurrences.model_validate(
            get_json(source.url, "/count", params, source.token, source.tenant)
        )
    try:
        memory = _open(source.data, *source.spaces, tenant=source.tenant)
        kw = scope.filters()
        if scope.session is not None:
            memory.session(scope.session)  # an unknown session is an error, as over HTTP
        return memory.occurrences(query, group=group, sort=sort, threshold=threshold, **kw)
    except TactusError as exc:
        fail(str(exc))


def _aligned(item: Any) -> str:
    """An item's span on the session clock."""
    return fmt_span(item.t_aligned, item.t_end_aligned)


def _print_moment(which: str, query: str, found: Occurrences, as_json: bool) -> None:
    moment = None
    if found.moments:
        moment = found.moments[-1] if which == "last" else found.moments[0]
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
            *(_aligned(e), e.sense, f"{e.score:.2f}"),
            *(match_cell(e.score, e.match, e.bar), e.id, e.text or ""),
        ),
        overflow="fold",
    )


def _print_count(query: str, found: Occurrences, as_json: bool) -> None:
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


def _question(name: str, doc: str, show: Callable[[str, Occurrences, bool], None]) -> None:
    """Register ``tactus NAME QUERY``: the occurrences of QUERY in scope, shown by ``show``."""

    @app.command(name, help=doc)
    @grouped(scope=Scope, source=Source)
    def ask(
        query: str = Query,
        *,
        scope: Scope,
        as_json: AsJson = False,
        source: Source,
        windows: Windows = False,
        sort: Sort = None,
        threshold: Threshold = None,
    ) -> None:
        show(query, _occurrences(query, scope, source, windows, sort, threshold), as_json)


_question(
    "last",
    "When did it last happen? The latest occurrence and its evidence across senses.",
    functools.partial(_print_moment, "last"),
)
_question(
    "first",
    "When did it first happen? The earliest occurrence and its evidence across senses.",
    functools.partial(_print_moment, "first"),
)
_question(
    "count",
    "How many distinct times did it happen? Each occurrence with its time and senses.",
    _print_count,
)


@app.command("timeline")
@grouped(window=Window, source=Source)
def timeline(
    session: str = typer.Argument(..., help="The session to lay out in time order."),
    *,
    window: Window,
    episodes: bool = typer.Option(
        False, "--episodes", help="Episodes (coherent stretches of one stream), not items."
    ),
    limit: int | None = typer.Option(None, "--limit", min=1, help="Only the first LIMIT."),
    as_json: AsJson = False,
    source: Source,
) -> None:
    """A session in time order: its items, or its episodes, on the session clock.

    A read: episodes not yet stored are computed for the answer, not written."""
    from tactus_memory.errors import TactusError
    from tactus_memory.results import Episode, TimelineItem

    one_source(source.data, source.url)
    if source.url:
        params = {**dataclasses.asdict(window), "limit": limit, "episodes": str(episodes).lower()}
        path = session_path(session, "/timeline")
        answer = get_json(source.url, path, params, source.token, source.tenant)
        rows: list[Any] = [
            (Episode if episodes else TimelineItem).model_validate(r)
            for r in answer["episodes" if episodes else "items"]
        ]
    else:
        try:
            memory = _open(source.data, *source.spaces, tenant=source.tenant)
            rows = memory.timeline(session, **window.filters(), episodes=episodes, limit=limit)
        except TactusError as exc:
            fail(str(exc))
    if episodes:  # one row an episode, or one an item
        what, columns = "episode", ("t", "sense", "source", "episode", "items", "representative")
        row: Callable[[Any], tuple[str, ...]] = lambda e: (  # noqa: E731
            *(_aligned(e), e.sense, e.source),
            *(str(e.episode), str(e.n), e.representative),
        )
    else:
        what, columns = "item", ("t", "sense", "source", "id", "text")
        row = lambda it: (_aligned(it), it.sense, it.source, it.id, it.text or "")  # noqa: E731
    _print_results(
        rows,
        as_json=as_json,
        title=f"session {session}: {plural(len(rows), what)}",
        columns=columns,
        row=row,
        overflow="ellipsis" if episodes else "fold",
    )
