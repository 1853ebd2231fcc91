"""The Typer app behind the ``tactus`` console script. Sub-command modules register on it;
:data:`PANELS` groups and orders the commands in ``tactus --help``."""

from __future__ import annotations

import os
import sys
from typing import Any

import click
import typer
from typer.core import TyperGroup

#: ``tactus --help``: panel -> its commands, in the order shown (a command not listed here
#: is shown last, under Typer's own "Commands" panel)
PANELS: dict[str, tuple[str, ...]] = {
    "Serve and maintain a memory": ("serve", "mcp", "maintain", "keys", "audit"),
    "Ask the memory (add --url to ask a running server)": (
        "search",
        "last",
        "first",
        "count",
        "timeline",
        "sessions",
    ),
    "Recordings: ROS 2 bags and MCAP in, Rerun out": ("ingest", "export"),
    "Data sets": ("data",),
    "Touch encoder: train and evaluate": (
        "pretrain",
        "train",
        "adapt",
        "eval",
        "baseline",
        "ablate",
    ),
}
#: what a command may raise that the command line answers itself (usage errors, exits): Typer's
#: own click (its ClickException, the base of typer.BadParameter) and click's
KEPT: tuple[type[BaseException], ...] = (
    typer.Exit,
    typer.Abort,
    *(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"),
    click.exceptions.ClickException,
    click.exceptions.Exit,
    click.exceptions.Abort,
)
#: the exit status of a command that failed (click's usage errors also exit 2)
EXIT_FAILED = 2
_ORDER = {name: i for i, name in enumerate(n for names in PANELS.values() for n in names)}


def _plain_flags(cmd: Any) -> None:
    """Show boolean flags as ``--json``, not ``--json <bool>`` (Typer's rich help prints
    every option's type; a flag takes no value), in ``cmd`` and its sub-commands."""
    for param in cmd.get_params(cmd.context_class(cmd)):
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    for sub in getattr(cmd, "commands", {}).values():
        _plain_flags(sub)


class TactusGroup(TyperGroup):
    """The top-level group: commands in :data:`PANELS` order and panels, plain flags."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for panel, names in PANELS.items():
            for name in names:
                if name in self.commands:
                    self.commands[name].rich_help_panel = panel
        _plain_flags(self)

    def invoke(self, ctx: Any) -> Any:
        """A command that fails says so in one line on stderr and exits 2, never with a
        traceback (``TACTUS_DEBUG=1`` shows it); click's own errors and exits are kept."""
        try:
            return super().invoke(ctx)
        except KEPT:
            raise
        except Exception as exc:
            if os.environ.get("TACTUS_DEBUG"):
                raise
            message = " ".join(str(exc).split()) or type(exc).__name__
            print(f"error: {message} ({type(exc).__name__})", file=sys.stderr)
            raise typer.Exit(EXIT_FAILED) from exc

    def list_commands(self, ctx: Any) -> list[str]:
        names = super().list_commands(ctx)
        return sorted(names, key=lambda name: _ORDER.get(name, len(_ORDER)))


app = typer.Typer(
    name="tactus",
    cls=TactusGroup,
    help="tactus-memory: a robot memory where touch is a language-searchable sense.",
    no_args_is_help=True,
    add_completion=False,
)
