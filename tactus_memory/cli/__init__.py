"""``tactus`` command line. Each module below registers its commands on the shared app.

Heavy imports (torch, LanceDB, the service) happen inside the commands, so ``tactus --help``
is instant. ``tactus serve`` imports the service lazily: the CLI is the application layer;
the library core (memory, spaces, senses, touch) never imports the service.
"""

from __future__ import annotations

from tactus_memory.cli import (  # noqa: F401  (imported for their registrations)
    ask_cmds,
    data_cmds,
    demo_cmd,
    eval_cmds,
    keys_cmds,
    maintain_cmd,
    mcp_cmd,
    memory_cmds,
    recipe_cmds,
    recording_cmds,
    serve_cmd,
    train_cmds,
)
from tactus_memory.cli.app import app


def main() -> None:
    app()
