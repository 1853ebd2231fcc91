"""Commands: serve_cmd."""

from tactus_memory.cli.app import app  # noqa: F401
