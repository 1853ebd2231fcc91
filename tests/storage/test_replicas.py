"""Several processes, one store (issue 11): bounded staleness between replicas, caches that
follow the table version, concurrent appends that lose nothing, one maintainer
(``tactus maintain``), and two real ``tactus serve --no-maintain`` replicas over HTTP."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from datetime import timedelta
from pathlib import Path

import lance
import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.settings import Settings
from tactus_memory.storage.connect import read_consistency_interval, storage_options_for
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace
from tests.helpers.replicas import STALENESS, open_replica, start_writer, wait_for


def _replica(path: Path, *, maintain: bool = False) -> Memory:
    return open_replica(str(path), maintain=maintain)


# ------------------------------------------------------------------ settings
def test_read_consistency_from_env_and_arguments(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Storage takes the interval it is given (1 s by default) and reads no settings; the
    settings read ``TACTUS_READ_CONSISTENCY`` and ``Memory.open`` passes it down."""
    monkeypatch.setenv("TACTUS_READ_CONSISTENCY", "0.25")
    assert read_consistency_interval() == timedelta(seconds=1)  # storage: no env
    assert Settings().read_consistency == 0.25
    mem = Memory.open(str(tmp_path / "m"), space=HashingSpace(), background=False)
    assert mem.store.read_consistency == timedelta(seconds=0.25)
    monkeypatch.setenv("TACTUS_READ_CONSISTENCY", "off")
    assert Settings().read_consistency is None
    assert read_consistency_interval(Settings().read_consistency) is None
    assert read_consistency_interval(2) == timedelta(seconds=2)
    assert read_consistency_interval(None) is None
    with pytest.raises(InvalidInputError, match="read consistency"):
        read_consistency_interval(-1)


def test_s3_storage_options_come_from_the_aws_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:9")
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "key")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "secret")
    monkeypatch.setenv("AWS_REGION", "eu-west-1")
    opts = storage_options_for("s3://bucket/prefix")
    assert opts == {
        "aws_endpoint": "http://127.0.0.1:9",
        "aws_access_key_id": "key",
        "aws_secret_access_key": "secret",
        "aws_region": "eu-west-1",
        "allow_http": "true",  # a plain-http endpoint (a local S3-compatible server)
    }
    given = storage_options_for("s3://bucket/prefix", {"aws_region": "us-east-1"})
    assert given["aws_region"] == "us-east-1"  # explicit options win
    assert storage_options_for("/local/dir") == {}  # the AWS env is for s3:// only


# ------------------------------------------------------------------ in-process replicas
def test_replicas_see_each_others_rows_and_senses_within_the_bound(tmp_path: Path) -> None:
    a = _replica(tmp_path / "m", maintain=True)
    b = _replica(tmp_path / "m")
    assert b.sense_info()[0].rows == 0  # b's count cache is primed (and empty)
    a.add("s1", "text", "the red mug is on the shelf")
    # the bound is the connection's re-read interval; how long visibility takes on a given
    # machine is measured by benchmarks/fleet.py, not asserted here (a loaded CPU stretches it)
    assert b.store.read_consistency == timedelta(seconds=STALENESS)
    wait_for(lambda: {s.name: s.rows for s in b.sense_info()}.get("text") == 1)
    assert [h.text for h in b.search("red mug", k=1)] == ["the red mug is on the shelf"]
    # a sense registered and written by the other replica shows up with its rows
    a.add_sense(VectorSense("motion", dim=a.space.dim))
    a.add_many("s1", "motion", list(np.random.default_rng(0).standard_normal((3, 64))))
    wait_for(lambda: {s.name: s.rows for s in b.sense_info()}.get("motion") == 3)
    assert {h.sense for h in b.search("red mug", k=10)} == {"text", "motion"}
    # b's own writes and a's interleave; both count everything
    b.add("s1", "text", "a note from b")
    a.add("s1", "text", "a note from a")
    wait_for(lambda: len(a) == len(b) == 6)
    wait_for(lambda: {s.name: s.rows for s in a.sense_info()}["text"] == 3)
    wait_for(lambda: {s.name: s.rows for s in b.sense_info()}["text"] == 3)


def test_a_replica_reads_on_through_the_maintainers_compaction_and_cleanup(
    tmp_path: Path,
) -> None:
    cfg = MaintenanceConfig(maintain=True, retain_seconds=0.5, fan_in=2)
    owner = Memory.open(
        str(tmp_path / "m"), HashingSpace(), read_consistency_interval=STALENESS, maintenance=cfg
    )
    reader = _replica(tmp_path / "m")
    for i in range(12):
        owner.add("s1", "text", f"note {i} about the mug")
    wait_for(lambda: len(reader) == 12)
    assert reader.search("mug", k=3)
    owner.optimize()
    time.sleep(1.0)
    owner.add("s1", "text", "one more note")
    owner.optimize()  # the versions the reader saw are superseded > 0.5 s: removed
    assert owner.store.last_maintenance[0].versions_removed > 0
    # the reader moves to the latest version within its staleness bound and reads on
    wait_for(lambda: len(reader) == 13)
    assert len(reader.search("mug", k=20)) == 13


# ------------------------------------------------------------------ processes
def test_two_processes_appending_concurrently_lose_nothing(tmp_path: Path) -> None:
    data = str(tmp_path / "m")
    Memory.open(data, HashingSpace()).close()  # create the tables once
    n = 40
    # two replicas writing, one of them also the maintainer (compacting under the other)
    procs = [start_writer(data, "a", n, "--maintain"), start_writer(data, "b", n)]
    acked = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-2000:]
        acked += [line for line in out.splitlines() if line != "ready"]
    assert len(acked) == 2 * n
    mem = Memory.open(data, HashingSpace())
    ids = set(mem.store.scan(None, ["id"]).column("id").to_pylist())
    assert ids == set(acked)
    texts = mem.store.scan(None, ["text"]).column("text").to_pylist()
    assert sum("from a " in t for t in texts) == n and sum("from b " in t for t in texts) == n


def test_tactus_maintain_compacts_what_replicas_wrote(tmp_path: Path) -> None:
    data = tmp_path / "m"
    mem = Memory.open(
        str(data),
        HashingSpace(),
        maintenance=MaintenanceConfig(maintain=False),
        index=IndexConfig(compact_every=4),
    )
    for i in range(20):
        mem.add("s1", "text", f"note {i}")
    table = str(data / "items.lance")
    assert len(lance.dataset(table).get_fragments()) == 20  # the replica never compacted
    env = {**os.environ, "TACTUS_RETAIN_SECONDS": "0"}
    tactus = [sys.executable, "-c", "from tactus_memory.cli import main; main()"]
    res = subprocess.run(
        [*tactus, "maintain", "--data", str(data), "--once"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    reports = [json.loads(line) for line in res.stdout.splitlines()]
    items = next(r for r in reports if r["table"] == "items.lance")
    assert items["compacted_groups"] >= 1 and items["fragments"] < 20
    assert items["versions_removed"] > 0
    assert len(lance.dataset(table).get_fragments()) == items["fragments"]
    assert len(Memory.open(str(data), HashingSpace())) == 20
    missing = subprocess.run(
        [*tactus, "maintain", "--data", str(tmp_path / "nothing"), "--once"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert missing.returncode == 2 and "no memory" in missing.stderr
