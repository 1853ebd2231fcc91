"""``tactus`` command line. Each module below registers its commands on the shared app.

Heavy imports (torch, LanceDB, the service) happen inside the commands, so ``tactus --help``
is instant. ``tactus serve`` imports the service lazily: the CLI is the application layer;
the library core (memory, spaces, senses, touch) never imports the service.
"""

from __future__ import annotations

import sys

from tactus_memory.cli import prefetch

# `tactus serve`: read ahead, in a reader process, the files its start will read (a cold file
# cache), before the commands below import anything heavy
prefetch.start(sys.argv)

from tactus_memory.cli import (  # noqa: E402, F401  (imported for their registrations)
    adapt_cmd,
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
from tactus_memory.cli.app import app  # noqa: E402


def main() -> None:
    app()
