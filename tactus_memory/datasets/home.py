"""Where the project's data files live: ONE function, used by the CLI and the tests.

Resolution (first that applies):

1. ``TACTUS_DATA_HOME`` set: that folder, and nothing else (no fallback, so a test run can point
   it at an empty folder and see what a stranger sees);
2. the user's data folder, ``$XDG_DATA_HOME/tactus`` (default ``~/.local/share/tactus``;
   ``%LOCALAPPDATA%\\tactus`` on Windows) when it holds STAG files;
3. ``../shared/data`` beside a source checkout (the development layout), when it holds STAG
   files;
4. otherwise the user's data folder of 2 (where ``tactus data fetch`` puts files).

STAG subsets sit under ``<data>/stag/<subset>/metadata.mat``.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

#: environment variable naming the data folder (overrides everything)
#: (not TACTUS_DATA: that is the memory store of `tactus serve` and the memory commands)
ENV_DATA = "TACTUS_DATA_HOME"
#: the STAG subsets, folder names as the dataset ships them
STAG = "stag"
#: the subsets ``tactus data fetch stag`` downloads, and the one the real-data tests need most
CORE_SUBSET = "weights_lite"
#: the repository root of a source checkout (``tactus_memory/..``); the fallback sits beside it
CHECKOUT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class DataHome:
    """The resolved data folder and why it was chosen (``env``, ``user``, ``checkout``)."""

    path: Path
    source: str

    @property
    def stag(self) -> Path:
        """``<data>/stag``: one folder per subset."""
        return self.path / STAG

    def stag_subsets(self) -> list[str]:
        """Names of the STAG subsets present (folders holding a ``metadata.mat``)."""
        return stag_subsets(self.stag)


def stag_subsets(stag_root: Path) -> list[str]:
    if not stag_root.is_dir():
        return []
    return sorted(p.name for p in stag_root.iterdir() if (p / "metadata.mat").is_file())


def user_data_dir() -> Path:
    """The per-user data folder (XDG on Linux/macOS, ``%LOCALAPPDATA%`` on Windows)."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or str(Path.home() / "AppData" / "Local")
    else:
        base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "tactus"


def checkout_data_dir() -> Path | None:
    """``../shared/data`` beside a source checkout, or None for an installed package."""
    if not (CHECKOUT / "pyproject.toml").is_file():
        return None
    return CHECKOUT.parent / "shared" / "data"


def data_home() -> DataHome:
    """The data folder (see the module docstring for the order)."""
    env = os.environ.get(ENV_DATA, "").strip()
    if env:
        return DataHome(Path(env).expanduser(), "env")
    user = DataHome(user_data_dir(), "user")
    if user.stag_subsets():
        return user
    shared = checkout_data_dir()
    if shared is not None and stag_subsets(shared / STAG):
        return DataHome(shared, "checkout")
    return user


def how_to_get_stag() -> str:
    """One line telling a person how to get the STAG files."""
    return (
        "get them with `tactus data fetch stag` (downloads the public lite subsets; "
        "`--from DIR` imports files you already have), or point "
        f"{ENV_DATA} at a folder holding stag/<subset>/metadata.mat"
    )
