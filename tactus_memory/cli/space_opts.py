"""The one space option set every command shares: ``--space NAME --space-path DIR
--space-dim N`` (environment ``TACTUS_SPACE``, ``TACTUS_SPACE_PATH``, ``TACTUS_SPACE_DIM``).

Commands declare the three parameters with these ``Annotated`` aliases and hand them to
:func:`space_choice` / :func:`resolve_or_exit`; the resolution itself is
:func:`tactus_memory.spaces.resolve.resolve_space`, the same function ``Memory.open`` and the
service use. A space that cannot be built is one line on stderr and exit status 2.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space
    from tactus_memory.spaces.resolve import SpaceChoice

SPACE_PANEL = "Embedding space"

SpaceName = Annotated[
    str | None,
    typer.Option(
        "--space",
        help="Space: minilm (default) or qwen3vl (Qwen3-VL-Embedding-2B, needs --space-path); "
        "an existing memory's recorded space when omitted (env TACTUS_SPACE).",
        rich_help_panel=SPACE_PANEL,
    ),
]
SpacePath = Annotated[
    str | None,
    typer.Option(
        "--space-path",
        help="Local model folder of the space (Qwen3-VL-Embedding-2B) (env TACTUS_SPACE_PATH).",
        rich_help_panel=SPACE_PANEL,
    ),
]
SpaceDim = Annotated[
    int | None,
    typer.Option(
        "--space-dim",
        min=1,
        help="Matryoshka output size for Qwen3-VL, 64..2048 (env TACTUS_SPACE_DIM).",
        rich_help_panel=SPACE_PANEL,
    ),
]


def fail(message: str) -> NoReturn:
    """One line on stderr, exit status 2 (bad usage or configuration)."""
    from rich.console import Console
    from rich.markup import escape

    # escaped: a message is text, not markup ("pip install 'tactus-memory[train]'" kept whole)
    Console(stderr=True, soft_wrap=True).print(
        f"[bold red]error:[/] {escape(message)}", highlight=False
    )
    raise typer.Exit(code=2)


def space_choice(space: str | None, space_path: str | None, space_dim: int | None) -> SpaceChoice:
    from tactus_memory.spaces.resolve import SpaceChoice

    return SpaceChoice(space, space_path, space_dim)


def resolve_or_exit(
    space: str | None,
    space_path: str | None,
    space_dim: int | None,
    recorded: dict[str, Any] | None = None,
    owner: str = "this memory",
) -> Space:
    """The named space (see ``resolve_space``), or a one-line error and exit 2."""
    from tactus_memory.errors import SpaceConfigError
    from tactus_memory.spaces.resolve import resolve_space

    try:
        return resolve_space(space_choice(space, space_path, space_dim), recorded, owner=owner)
    except SpaceConfigError as exc:
        fail(str(exc))
