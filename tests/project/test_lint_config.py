"""Lint results do not depend on what lies in the checkout: a memory store made by `make run`
(``./memory``) or by ``DATA=<any name> make run`` never turns a name into a first-party
package, so ``make run`` then ``make test`` in the same checkout lints as a fresh clone."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RUFF = Path(sys.prefix) / "bin" / "ruff"
LINTED = {".py", ".pyi", ".toml", ".md"}


def copy_sources(dest: Path) -> None:
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout.decode()  # fmt: skip
    for name in filter(None, listed.split("\0")):
        src = ROOT / name
        if src.suffix in LINTED and src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)


def ruff(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(RUFF), *args], cwd=cwd, capture_output=True, text=True)


def test_a_memory_store_in_the_checkout_does_not_change_lint_results(tmp_path: Path) -> None:
    clone = tmp_path / "clone"
    copy_sources(clone)
    # stores as `make run` and `DATA=... make run` leave them: named like modules the
    # benchmarks and tests import (benchmarks/memory.py, benchmarks/serving.py, numpy)
    for store in ("memory", "serving", "numpy", "places"):
        table = clone / store / "items.lance" / "data"
        table.mkdir(parents=True)
        (table / "0.lance").write_bytes(b"\0" * 64)
    done = ruff(clone, "check", "--no-cache", ".")
    assert done.returncode == 0, done.stdout + done.stderr
    done = ruff(clone, "format", "--check", "--no-cache", ".")
    assert done.returncode == 0, done.stdout + done.stderr
    # the copy is really linted: a misordered import in it is found
    (clone / "benchmarks" / "zz_unsorted.py").write_text("import numpy\nimport os\n\nos, numpy\n")
    done = ruff(clone, "check", "--no-cache", ".")
    assert done.returncode == 1 and "I001" in done.stdout, done.stdout
