"""Type-check the installed package as it is installed: ``tactus_memory`` with its two
folders mapped in by pyproject's package-dir (``service/`` as ``tactus_memory.service``,
``adapters/`` as ``tactus_memory.adapters``), which mypy cannot follow by itself (it reads the
source tree, not the editable install's import hook).

Builds a tree of symbolic links under ``build/typecheck/`` (every entry of ``tactus_memory/``
plus the two folders) and runs ``mypy -p tactus_memory`` there with the checkout's
configuration (``[tool.mypy]`` in pyproject.toml) and cache. Exit status: mypy's.

    python scripts/typecheck.py          # what `make lint` runs
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: installed subpackage -> its folder in the checkout (pyproject.toml: [tool.setuptools])
MAPPED = {"service": ROOT / "service", "adapters": ROOT / "adapters"}


def link_tree(dest: Path) -> Path:
    """``dest/tactus_memory``: links to the package's entries and the mapped folders."""
    pkg = dest / "tactus_memory"
    if pkg.exists():
        shutil.rmtree(pkg)
    pkg.mkdir(parents=True)
    for entry in (ROOT / "tactus_memory").iterdir():
        if entry.name not in MAPPED and entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name, folder in MAPPED.items():
        (pkg / name).symlink_to(folder)
    return pkg


def main() -> int:
    tree = ROOT / "build" / "typecheck"
    link_tree(tree)
    cmd = [
        sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
        "--cache-dir", str(ROOT / ".mypy_cache"), "-p", "tactus_memory", *sys.argv[1:],
    ]  # fmt: skip
    return subprocess.run(cmd, cwd=tree).returncode


if __name__ == "__main__":
    raise SystemExit(main())
