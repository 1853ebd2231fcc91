"""Where tactus keeps what it derives on this machine (the default server's ONNX models, the
start's read-ahead list): standard library only, so ``tactus serve`` can ask before it
imports anything heavy (:mod:`tactus_memory.cli.prefetch`)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """``$TACTUS_CACHE``, else ``$XDG_CACHE_HOME/tactus``, else ``~/.cache/tactus``."""
    if os.environ.get("TACTUS_CACHE"):
        return Path(os.environ["TACTUS_CACHE"])
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "tactus"
