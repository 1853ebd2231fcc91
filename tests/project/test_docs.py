"""The docs site builds with ``mkdocs build --strict`` (so a broken link, anchor or
``examples/`` include fails the suite), the README stays short, and the configuration
reference names every setting."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MKDOCS = Path(sys.prefix) / "bin" / "mkdocs"
README_MAX_LINES = 250


def build(root: Path, out: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    cmd = [str(MKDOCS), "build", "--strict", "--clean", "-f", str(root / "mkdocs.yml")]
    return subprocess.run(
        [*cmd, "-d", str(out)], cwd=root, capture_output=True, text=True, env=env, timeout=300
    )


def test_the_docs_build_strict(tmp_path: Path) -> None:
    done = build(ROOT, tmp_path / "site")
    assert done.returncode == 0, done.stdout + done.stderr
    site = tmp_path / "site"
    assert (site / "getting-started" / "index.html").is_file()
    python = (site / "reference" / "python" / "index.html").read_text()
    assert "search" in python and "Memory" in python  # the API reference from docstrings
    places = (site / "guides" / "places" / "index.html").read_text()
    assert "add_poses" in places and "--8&lt;--" not in places  # the example, included


@pytest.mark.parametrize(
    ("page", "old", "new"),
    [
        ("docs/guides/places.md", "](../getting-started.md", "](../no-such-page.md"),
        ("docs/guides/places.md", '--8<-- "examples/places.py"', '--8<-- "examples/gone.py"'),
        ("docs/guides/recordings.md", "(places.md#from-a-recording)", "(places.md#no-anchor)"),
    ],
)
def test_a_broken_link_or_include_fails_the_build(
    tmp_path: Path, page: str, old: str, new: str
) -> None:
    copy = tmp_path / "copy"
    copy.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in {"docs", ".git", ".venv", "site"}:
            (copy / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
    shutil.copytree(ROOT / "docs", copy / "docs")
    text = (copy / page).read_text()
    assert old in text, old
    (copy / page).write_text(text.replace(old, new, 1))
    done = build(copy, tmp_path / "site")
    assert done.returncode != 0, done.stdout + done.stderr


def test_readme_is_short_and_keeps_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= README_MAX_LINES
    assert "make run " in readme and "make test " in readme
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci  # CI calls the README's test command


def test_the_configuration_page_names_every_setting() -> None:
    from tactus_memory.settings import Settings

    page = (ROOT / "docs" / "reference" / "configuration.md").read_text()
    missing = [f for f in Settings.model_fields if f"`TACTUS_{f.upper()}`" not in page]
    assert not missing, missing
