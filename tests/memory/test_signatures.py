"""``signatures.grouped``: a group of parameters declared once stands in the signature the
frameworks read (Typer here) and comes back to the function as one object."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Annotated

import typer
from typer.testing import CliRunner

from tactus_memory.signatures import grouped


@dataclass(frozen=True)
class Window:
    after: Annotated[float | None, typer.Option("--after")] = None
    before: Annotated[float | None, typer.Option("--before")] = None


@grouped(window=Window)
def count(query: str, *, window: Window, k: int = 3) -> tuple[str, Window, int]:
    return query, window, k


def test_the_group_stands_in_place_and_comes_back_as_one_object() -> None:
    params = inspect.signature(count).parameters
    assert list(params) == ["query", "after", "before", "k"]
    assert params["after"].kind is inspect.Parameter.KEYWORD_ONLY
    assert count("mug", after=1.0, k=5) == ("mug", Window(after=1.0), 5)
    assert count("mug") == ("mug", Window(), 3)


def test_typer_reads_the_groups_flags() -> None:
    app = typer.Typer()
    seen: list[Window] = []

    @app.command()
    @grouped(window=Window)
    def main(*, window: Window) -> None:
        seen.append(window)

    result = CliRunner().invoke(app, ["--after", "2", "--before", "5.5"])
    assert result.exit_code == 0, result.output
    assert seen == [Window(after=2.0, before=5.5)]
    assert CliRunner().invoke(app, ["--window", "x"]).exit_code == 2  # no such flag
