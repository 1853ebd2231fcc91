"""Erasure that a crash cannot defeat (issue 36, defect 3). A ``maintain`` killed in the middle
of a compaction leaves files no version references, holding the rows it rewrote, deleted
ones included; ``tactus maintain`` removes such files once they are older than the orphan
grace, and never a younger one (it may be a writer's, mid-commit). Real LanceDB files: the
crash leftovers are copies of the store's own data and index files that no version names."""

from __future__ import annotations

import json
import os
import shutil
import time
import uuid
from pathlib import Path

import lance
from typer.testing import CliRunner

from tactus_memory.cli import app
from tactus_memory.memory.main import Memory
from tactus_memory.policies import ORPHAN_GRACE_S
from tactus_memory.storage.orphans import referenced, remove_orphans
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace

#: small enough that the scalar indexes (session, ...) exist, so an index folder is copied too
INDEX = IndexConfig(threshold=60, scalar_threshold=30, rows_per_partition=16)


def found(root: Path, needle: bytes) -> list[str]:
    """The files under ``root`` holding ``needle`` (every byte of every file)."""
    files = (p for p in root.rglob("*") if p.is_file())
    return sorted(str(p.relative_to(root)) for p in files if needle in p.read_bytes())


def age(path: Path, seconds: float) -> None:
    """Set the modification time of ``path`` (and of every file under it) ``seconds`` back."""
    when = time.time() - seconds
    for p in [path, *path.rglob("*")] if path.is_dir() else [path]:
        os.utime(p, (when, when))


def maintain(root: Path) -> list[dict]:
    res = CliRunner().invoke(app, ["maintain", "--once", "--retain", "0", "--data", str(root)])
    assert res.exit_code == 0, res.output
    return [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]


def test_maintain_removes_a_crashed_writers_files_past_the_grace_and_keeps_young_ones(
    tmp_path,
) -> None:
    secret = f"zq{uuid.uuid4().hex}"
    gone = f"gone-{secret}"
    root = tmp_path / "mem"
    mem = Memory.open(str(root), HashingSpace(), index=INDEX, background=False)
    for batch in range(8):  # kept rows around the needle: they share fragments
        mem.add_many("keep", "text", [f"kept note {batch}.{i}" for i in range(10)])
        if batch == 3:
            mem.add_many(gone, "text", [f"the {secret} note"])
    mem.optimize()  # merged and indexed: the needle sits in a data file and an index
    table = root / "items.lance"
    holding = found(root, secret.encode())
    data_file = next(f for f in holding if f.startswith("items.lance/data/"))
    index_dir = next(Path(f).parents[-3] for f in holding if "/_indices/" in f)

    # the crash leftovers: files a killed compaction and index build wrote, never committed
    old_data = table / "data" / f"{uuid.uuid4().hex}.lance"
    young_data = table / "data" / f"{uuid.uuid4().hex}.lance"
    old_index = table / "_indices" / str(uuid.uuid4())
    shutil.copyfile(root / data_file, old_data)
    shutil.copyfile(root / data_file, young_data)
    shutil.copytree(root / index_dir, old_index)
    age(old_data, ORPHAN_GRACE_S + 60)
    age(old_index, ORPHAN_GRACE_S + 60)
    leftovers = {old_data, young_data, old_index}
    refs = referenced(str(table))
    assert not {str(p.relative_to(table)) for p in leftovers} & refs  # no version names them
    assert data_file.removeprefix("items.lance/") in refs  # (the original is referenced)

    assert mem.delete_session(gone) == 1
    lines = maintain(root)
    items = next(line for line in lines if line["table"] == "items.lance" and "tenant" not in line)
    assert items["orphans_removed"] == 2  # the old data file and the old index folder
    assert not old_data.exists() and not old_index.exists()
    # only the young copy still holds the needle: inside the grace, it may be a writer's
    assert found(root, secret.encode()) == [str(young_data.relative_to(root))]

    age(young_data, ORPHAN_GRACE_S + 60)  # the grace has passed: now it is a crash's
    lines = maintain(root)
    assert sum(line.get("orphans_removed", 0) for line in lines) == 1
    assert found(root, secret.encode()) == []
    assert len(mem) == 80 and [s.id for s in mem.sessions()] == ["keep"]
    assert Memory.open(str(root), HashingSpace()).search("kept note", k=1)[0].session == "keep"


def test_files_any_kept_version_references_are_never_orphans(tmp_path) -> None:
    """With every file old and no grace at all, a sweep removes nothing a version still on
    disk needs: every kept version (not only the latest) reads back whole."""
    root = tmp_path / "mem"
    mem = Memory.open(str(root), HashingSpace(), index=INDEX, background=False)
    for batch in range(6):
        mem.add_many("s", "text", [f"note {batch}.{i}" for i in range(12)])
    mem.delete(mem.search("note 2.3", k=1)[0].id)  # a deletion file too
    mem.optimize()
    table = root / "items.lance"
    age(table, ORPHAN_GRACE_S + 60)
    sweep = remove_orphans(str(table), grace_seconds=0)
    assert sweep.removed == 0 and sweep.young == 0
    ds = lance.dataset(str(table))
    for v in ds.versions():
        assert ds.checkout_version(v["version"]).to_table() is not None
    assert len(mem) == 71
