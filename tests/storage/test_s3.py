"""Object storage against a real S3-compatible server (issue 11): moto's standalone server on
127.0.0.1 (a real HTTP S3 API, conditional PUT included; no Docker), a bucket made with boto3,
and the store at ``s3://bucket/prefix`` configured from the usual AWS environment variables.

Covered: the memory contract on s3://, two replicas writing concurrently (nothing lost, each
sees the other's rows within the staleness bound), a writer killed with SIGKILL (every
acknowledged row survives), ``tactus maintain`` on s3://, and ``tactus serve --data s3://``
replicas over real HTTP."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import httpx
import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import NotFoundError
from tests.helpers.replicas import STALENESS, open_replica, start_writer, wait_for
from tests.helpers.s3 import WAIT_S
from tests.helpers.servers import Server


# ------------------------------------------------------------------ the contract on s3://
def test_memory_contract_on_s3(uri: str) -> None:
    mem = open_replica(uri, maintain=True)
    assert mem.store.storage_options["allow_http"] == "true"  # from the http:// endpoint
    a = mem.add("kitchen", "text", "put the red mug on the shelf", t=1.0, meta={"by": "op"})
    mem.add_many("kitchen", "text", ["a soft sponge", "a cold spoon"], t=[2.0, 3.0])
    mem.add("garage", "text", "a rough brick", t=4.0)
    mem.add_sense(VectorSense("motion", dim=mem.space.dim))
    mem.add_many("garage", "motion", list(np.random.default_rng(0).standard_normal((2, 64))))
    mem.add("kitchen", "text", "the mug is blue now", id="fixed-1")
    mem.add("kitchen", "text", "the mug is green now", id="fixed-1")  # upsert
    hits = mem.search("red mug", k=2, senses=["text"], session="kitchen")
    assert hits[0].id == a and hits[0].meta == {"by": "op"}
    assert mem.get_item("fixed-1").text == "the mug is green now"
    assert [s.id for s in mem.sessions()] == ["garage", "kitchen"]
    assert mem.session("kitchen").counts == {"text": 4}
    assert mem.session("garage").counts == {"motion": 2, "text": 1}
    mem.optimize()  # maintenance on object storage too
    assert mem.delete([a]) == 1
    with pytest.raises(NotFoundError):
        mem.get_item(a)
    assert mem.delete_session("garage") == 3
    again = open_replica(uri, maintain=True)  # a fresh connection reads the same store back
    assert len(again) == 3
    assert [s.id for s in again.sessions()] == ["kitchen"]
    assert {s.name: s.rows for s in again.sense_info()} == {"motion": 0, "text": 3}


def test_two_replicas_write_concurrently_and_see_each_other(
    uri: str, aws_env: dict[str, str]
) -> None:
    a = open_replica(uri, maintain=True)
    b = open_replica(uri, maintain=False)
    a.add("s1", "text", "the red mug from a")
    assert b.store.read_consistency == timedelta(seconds=STALENESS)  # the bound; its timing:
    wait_for(lambda: len(b.search("red mug", k=5)) == 1, WAIT_S)  # benchmarks/fleet.py
    b.add("s1", "text", "a blue cup from b")
    wait_for(lambda: {s.name: s.rows for s in a.sense_info()}["text"] == 2, WAIT_S)
    # two processes appending at once (one is the maintainer, compacting meanwhile)
    n = 25
    procs = [
        start_writer(uri, "p", n, "--maintain", env=aws_env),
        start_writer(uri, "q", n, env=aws_env),
    ]
    acked: list[str] = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-3000:]
        acked += [line for line in out.splitlines() if line != "ready"]
    assert len(acked) == 2 * n
    wait_for(lambda: len(b) == 2 * n + 2, WAIT_S)
    ids = set(b.store.scan(None, ["id"]).column("id").to_pylist())
    assert set(acked) <= ids and len(ids) == 2 * n + 2


def test_acknowledged_rows_survive_a_killed_writer(uri: str, aws_env: dict[str, str]) -> None:
    open_replica(uri, maintain=True).close()  # the tables exist before the writer starts
    proc = start_writer(uri, "k", 10_000, "--delay", "0.02", env=aws_env)
    acked: list[str] = []
    assert proc.stdout is not None
    try:
        assert proc.stdout.readline().strip() == "ready"
        while len(acked) < 15:
            line = proc.stdout.readline().strip()
            assert line, proc.stderr.read() if proc.stderr else "writer ended"
            acked.append(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    assert proc.returncode == -signal.SIGKILL
    mem = open_replica(uri, maintain=True)
    ids = set(mem.store.scan(None, ["id"]).column("id").to_pylist())
    assert set(acked) <= ids  # every acknowledged row is there
    assert len(ids) <= len(acked) + 2  # at most the rows in flight at the kill besides
    mem.add("s1", "text", "the store still takes writes")  # and is not corrupt
    assert len(mem) == len(ids) + 1


def test_tactus_maintain_on_s3(uri: str, aws_env: dict[str, str]) -> None:
    replica = open_replica(uri, maintain=False)
    for i in range(12):
        replica.add("s1", "text", f"note {i}")
    tactus = [sys.executable, "-c", "from tactus_memory.cli import main; main()"]
    res = subprocess.run(
        [*tactus, "maintain", "--data", uri, "--passes", "2", "--interval", "0.5", "--retain", "0"],
        capture_output=True,
        text=True,
        env={**os.environ, **aws_env},
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    import json

    reports = [json.loads(line) for line in res.stdout.splitlines()]
    items = [r for r in reports if r["table"] == "items.lance"]
    assert len(items) == 2 and items[0]["compacted_groups"] >= 1
    assert items[-1]["fragments"] < 12
    wait_for(lambda: len(replica) == 12, WAIT_S)
    assert len(replica.search("note", k=20)) == 12  # the replica reads on after cleanup


# ------------------------------------------------------------------ real HTTP
def _serve(uri: str, env: dict[str, str], log: Path, *extra: str) -> Server:
    """``tactus serve --data s3://...`` without touch, reading others' commits every STALENESS s."""
    return Server(
        uri, log, "--no-touch", *extra, env={**env, "TACTUS_READ_CONSISTENCY": str(STALENESS)}
    )


@pytest.mark.slow
def test_two_serve_replicas_on_s3_over_http(
    uri: str, aws_env: dict[str, str], tmp_path: Path
) -> None:
    first = _serve(uri, aws_env, tmp_path / "a.log")  # owns maintenance
    second = None
    try:
        second = _serve(uri, aws_env, tmp_path / "b.log", "--no-maintain")
        r = httpx.post(
            first.base + "/sessions/kitchen/text",
            json={"text": "put the red mug on the shelf", "t": 1.0},
            timeout=60,
        )
        assert r.status_code == 201, r.text
        item = r.json()["ids"][0]

        def second_sees() -> bool:
            senses = httpx.get(second.base + "/senses", timeout=30).json()["senses"]
            return {s["name"]: s["rows"] for s in senses}.get("text") == 1

        wait_for(second_sees, timeout=60)
        hits = httpx.get(
            second.base + "/search", params={"q": "a mug on a shelf", "k": 1}, timeout=60
        ).json()["hits"]
        assert [h["id"] for h in hits] == [item]
        note = {"text": "a soft sponge", "t": 2.0}
        r = httpx.post(second.base + "/sessions/kitchen/text", json=note, timeout=60)
        assert r.status_code == 201, r.text
        wait_for(
            lambda: httpx.get(first.base + "/sessions/kitchen", timeout=30).json()["n"] == 2,
            timeout=WAIT_S,
        )
    finally:
        first.stop()
        if second is not None:
            second.stop()
