"""The Typer app behind the ``tactus`` console script. Sub-command modules register on it."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="tactus",
    help="tactus-memory: a robot memory where touch is a language-searchable sense.",
    no_args_is_help=True,
    add_completion=False,
)
