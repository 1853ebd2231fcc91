"""Commands: memory_cmds."""

from tactus_memory.cli.app import app  # noqa: F401
