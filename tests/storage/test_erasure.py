"""Deletion that leaves nothing behind (issue 25): after ``DELETE /sessions/{id}`` on a real
uvicorn, or expiry, and maintenance (compaction, then cleanup past ``retain_seconds``), no
byte of any file of the store holds the deleted data, indexes, old versions and other
tables included. Real MiniLM, the real Tactus encoder, real LanceDB files."""

from __future__ import annotations

import time
import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest

from benchmarks.serving import serve_app
from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.tables import IndexConfig

#: small enough that the scalar indexes (id, session, ...) and the ANN index exist, so
#: their files are searched too
INDEX = IndexConfig(threshold=60, scalar_threshold=30, rows_per_partition=16)


def found(root: Path, needles: dict[str, bytes]) -> dict[str, list[str]]:
    """Which needles occur in which files under ``root`` (every byte of every file). A file
    the running server's cleanup removes between the listing and the read held nothing more."""
    where: dict[str, list[str]] = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            continue
        for name, needle in needles.items():
            if needle in data:
                where.setdefault(name, []).append(str(path.relative_to(root)))
    return where


def test_deleted_and_expired_data_leave_no_byte_in_the_store(tmp_path, minilm_space) -> None:
    secret = f"zq{uuid.uuid4().hex}"  # a string no other row, file or format holds
    gone, expiring = f"gone-{secret}", f"exp-{secret}"
    settings = Settings(
        retain_seconds=0,  # the version retention window, shortened for the test
        cleanup_interval=0,
        retention_interval=3600,  # one pass during the setup (nothing old yet), one forced
        retention=[{"session": "exp-*", "retain_days": 1e-5}],  # 0.86 s
    )
    root = tmp_path / "mem"
    mem = Memory.open(
        str(root), space=minilm_space, maintenance=settings.maintenance(), index=INDEX,
        background=False,
    )  # fmt: skip
    mem.add_sense(TactusEncoder())
    rng = np.random.default_rng(7)
    window = rng.uniform(0.3, 0.9, (8, 32, 32)).astype(np.float32)  # (K, 32, 32) calibrated
    place = 4321.123456789  # a unique coordinate of the deleted session's trajectory
    for batch in range(6):  # kept rows around the deleted ones: they share fragments
        mem.add_many("keep", "text", [f"kept note {batch}.{i}" for i in range(10)])
        if batch == 2:
            mem.add_many(gone, "text", [f"the {secret} note", "an ordinary note"])
            mem.add(gone, "touch", window, options={"calibrated": True}, id=f"w-{secret}")
            mem.add_poses(gone, [0.0, 1.0], [[place, 1.0, 0.0], [place, 2.0, 0.0]])
            mem.set_clock_offset(gone, "touch", 0.25)
            mem.add_many(expiring, "text", [f"expiring {secret[::-1]} note"])
    mem.optimize()  # fragments merged, indexes built: the rows sit among kept ones
    vector = np.asarray(mem.get_item(f"w-{secret}", vector=True).vector, np.float32)
    needles = {
        "session": gone.encode(),
        "text": f"the {secret} note".encode(),
        "expired text": secret[::-1].encode(),
        # the window is stored as float16 .npy (TactusEncoder.to_row), the embedding as float32
        "window": window.astype(np.float16).tobytes()[2048:2112],
        "vector": vector.tobytes()[512:576],
        "pose": np.float64(place).tobytes(),
    }
    before = found(root, needles)
    assert set(before) == set(needles), before  # the control: each needle is findable
    assert any("_indices" in f for f in before["session"])  # in an index file too

    app = create_app(settings, memory=mem)
    with serve_app(app) as base:
        headers = {"Accept": "application/json"}
        answer = httpx.delete(f"{base}/sessions/{gone}", headers=headers, timeout=60)
        assert answer.status_code == 200, answer.text
        assert answer.json()["deleted"] == 3 and answer.json()["clock_offsets"] == 1
        time.sleep(1.0)  # the expiring note is now older than its 1e-5 days
        assert mem.store.retention.run(force=True).expired == 1  # as a due pass does
        mem.optimize()  # a maintenance pass: compaction, cleanup
        status = httpx.get(f"{base}/retention", timeout=30).json()
    assert status["expired"] == 1 and status["erasure_pending"] is False
    assert status["rules"] == 1 and status["maintained_here"] is True
    assert found(root, needles) == {}
    assert len(mem) == 60 and [s.id for s in mem.sessions()] == ["keep"]
    assert mem.search("kept note", k=1)[0].session == "keep"  # the store still answers


def test_an_idle_server_erases_a_deleted_session_by_itself(tmp_path, minilm_space) -> None:
    """No explicit maintenance: the serving process's own passes (after the DELETE's commit,
    then its idle ticks every ``maintain_interval``) compact and clean the store."""
    secret = f"zq{uuid.uuid4().hex}"
    settings = Settings(retain_seconds=0.5, cleanup_interval=0, maintain_interval=0.2)
    root = tmp_path / "mem"
    mem = Memory.open(str(root), space=minilm_space, maintenance=settings.maintenance())
    for batch in range(10):  # fan_in (8) fragments and more: the deleted row shares one
        mem.add_many("keep", "text", [f"kept note {batch}.{i}" for i in range(5)])
        if batch == 4:
            mem.add_many(f"gone-{secret}", "text", [f"the {secret} note"])
    mem.optimize()
    needles = {"session": f"gone-{secret}".encode(), "text": f"the {secret} note".encode()}
    assert set(found(root, needles)) == set(needles)
    with serve_app(create_app(settings, memory=mem)) as base:
        assert httpx.delete(f"{base}/sessions/gone-{secret}", timeout=60).status_code == 200
        deadline = time.monotonic() + 120  # a liveness bound, not a speed target
        while httpx.get(f"{base}/retention", timeout=30).json()["erasure_pending"]:
            assert time.monotonic() < deadline, "the deleted rows were never erased"
            time.sleep(0.2)
        mem.wait_for_maintenance(60)
        mem.store.wait_for_cleanup(60)
    assert found(root, needles) == {}


def test_without_erasure_the_deleted_rows_stay_in_the_files(tmp_path, minilm_space) -> None:
    """The same delete with ``erase_deleted`` off: the data file still holds the row (so
    the test above can fail, and the setting is what erases)."""
    secret = f"zq{uuid.uuid4().hex}"
    cfg = Settings(retain_seconds=0, cleanup_interval=0, erase_deleted=False).maintenance()
    root = tmp_path / "mem"
    mem = Memory.open(str(root), space=minilm_space, maintenance=cfg, background=False)
    for batch in range(6):
        mem.add_many("keep", "text", [f"kept note {batch}.{i}" for i in range(10)])
        if batch == 2:
            mem.add_many(f"gone-{secret}", "text", [f"the {secret} note"])
    mem.optimize()
    assert mem.delete_session(f"gone-{secret}") == 1
    mem.optimize()
    assert "text" in found(root, {"text": f"the {secret} note".encode()})
    assert mem.store.erasure.pending()


@pytest.fixture(autouse=True)
def _no_env_retention(monkeypatch) -> None:
    for name in ("TACTUS_RETENTION", "TACTUS_RETAIN_DAYS", "TACTUS_THIN_AFTER_DAYS"):
        monkeypatch.delenv(name, raising=False)


#: a script that deletes a session and ends at once: the delete schedules a background
#: maintenance pass (erasure) that is still inside Lance's native code when Python exits
DELETE_AND_EXIT = """
import sys
import numpy as np
from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.memory.main import Memory

memory = Memory.open(sys.argv[1])
memory.add_sense(TactusEncoder())
memory.add("s2", "text", "put the mug on the shelf", t=3.0)
window = np.full((8, 32, 32), 512, np.int16)
window[:, 10:22, 8:20] = 640
memory.add("s2", "touch", window, t=2.5, t_end=3.6)
print(memory.delete_session("s2"))
"""


def test_a_script_that_deletes_and_exits_at_once_exits_cleanly(tmp_path) -> None:
    """The interpreter waits for background maintenance at exit (bounded): without it, 3 of
    4 such runs aborted (SIGABRT, exit 134) while the erasure pass was compacting, so two runs
    catch it 15 times in 16."""
    import subprocess
    import sys

    for i in range(2):
        done = subprocess.run(
            [sys.executable, "-c", DELETE_AND_EXIT, str(tmp_path / f"m{i}")],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
        assert done.stdout.strip().splitlines()[-1] == "2"


def test_an_idle_server_erases_and_expires_in_every_tenant(tmp_path, minilm_space) -> None:
    """Issue 36: the idle ticks maintain every tenant, not the default one only. Tenant B
    deletes a session through the API (its own key) and holds an expiring note; tenant C is
    never asked by anyone: both are erased and expired by the server's own passes, and B's
    ``/retention`` (B's key) reports B's own counts."""
    from tactus_memory.storage.keys import KeyStore

    secret = f"zq{uuid.uuid4().hex}"
    settings = Settings(
        retain_seconds=0.5,
        cleanup_interval=0,
        maintain_interval=0.2,
        retention_interval=0.2,
        retention=[{"session": "exp-*", "retain_days": 1e-5}],  # 0.86 s
    )
    root = tmp_path / "mem"
    mem = Memory.open(str(root), space=minilm_space, maintenance=settings.maintenance())
    mem.add("home", "text", "a default note", t=1.0)
    setup = Settings(retain_seconds=0.5, cleanup_interval=0).maintenance()  # no expiry here
    for tenant in ("B", "C"):
        other = Memory.open(str(root), space=minilm_space, maintenance=setup, tenant=tenant)
        for batch in range(10):  # fragments the deleted rows share with kept ones
            other.add_many("keep", "text", [f"kept note {batch}.{i}" for i in range(5)])
            if batch == 4:
                other.add_many(f"gone-{secret}", "text", [f"the {tenant} {secret} note"])
                other.add_many(f"exp-{secret}", "text", [f"expiring {tenant} {secret[::-1]}"])
        other.optimize()
        other.wait_for_maintenance(60)
        other.close()
    _, b_admin = KeyStore(str(root)).create("B", "admin")
    needles = {
        f"{t} {what}": text.encode()
        for t in ("B", "C")
        for what, text in (
            ("deleted", f"the {t} {secret} note"),
            ("expired", f"expiring {t} {secret[::-1]}"),
        )  # fmt: skip
    }
    folders = {t: root / "tenants" / t for t in ("B", "C")}
    assert set(found(folders["B"], needles)) == {"B deleted", "B expired"}  # the control
    assert set(found(folders["C"], needles)) == {"C deleted", "C expired"}
    auth = {"Authorization": f"Bearer {b_admin}"}
    with serve_app(create_app(settings, memory=mem)) as base:
        r = httpx.delete(f"{base}/sessions/gone-{secret}", headers=auth, timeout=60)
        assert r.status_code == 200 and r.json()["deleted"] == 1, r.text
        deadline = time.monotonic() + 180  # a liveness bound, not a speed target
        while True:
            status = httpx.get(f"{base}/retention", headers=auth, timeout=30).json()
            left = {**found(folders["B"], needles), **found(folders["C"], needles)}
            left.pop("C deleted", None)  # nobody deleted C's session: it stays
            if status["expired_total"] == 1 and not status["erasure_pending"] and not left:
                break
            assert time.monotonic() < deadline, (
                {k: status[k] for k in ("expired_total", "erasure_pending")},
                left,
            )
            time.sleep(0.3)
    assert set(found(folders["C"], needles)) == {"C deleted"}
    assert found(folders["B"], needles) == {}
    assert [i.text for i in mem.timeline("home")] == ["a default note"]
