"""Bulk work on Ray (issue 28): ``tactus ingest --ray`` and ``tactus reembed --ray`` on a
local Ray instance (2 CPUs, 2 workers, started once for this module) give what the local
path gives: the same ids, rows and places, vectors equal within float tolerance, and a
re-run adds nothing. Real parts: MCAP files and a ROS 2 bag written by their own libraries,
MiniLM, the shipped touch encoder, a real tactus-tiny checkpoint pair for the re-embedding."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.recordings import samples as rf
from tactus_memory.recordings.ingest import ingest_recording
from tactus_memory.recordings.ray_jobs import LOCAL, connect, ingest_on_ray
from tests.helpers.recording_files import N_FRAMES, TOPICS, _messages
from tests.helpers.service import make_memory
from tests.helpers.touch_pair import Pair, train_pair

pytestmark = pytest.mark.slow

#: a bound on every test here (Ray starting on a busy 2-core machine included)
TEST_SECONDS = 480
COLUMNS = ["id", "session", "sense", "source", "t", "t_end", "meta", "text", "raw", "x", "y", "z",
           "frame", "placed"]  # fmt: skip
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _bounded() -> Iterator[None]:
    def stop(*_: object) -> None:
        raise TimeoutError(f"a Ray test ran past {TEST_SECONDS} s")

    old = signal.signal(signal.SIGALRM, stop)
    signal.alarm(TEST_SECONDS)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def local_ray() -> Iterator[int]:
    """One local Ray instance for the module: 2 CPUs, so 2 one-CPU workers."""
    why = "the ray extra is not installed (pip install -e '.[ray]')"
    ray = pytest.importorskip("ray", reason=why)
    pytest.importorskip("lance_ray", reason=why)
    workers = connect(LOCAL, workers=2)
    try:
        yield workers
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> list[Path]:
    """Two MCAP files (one with odometry, so items are placed) and a ROS 2 bag."""
    root = tmp_path_factory.mktemp("recs")
    odom = [rf.odometry("/odom", _messages()[0].log_ns + k * rf.NS // 2, (k * 0.5, 1.0, 0.0),
                        (0.0, 0.0, 0.0, 1.0)) for k in range(8)]  # fmt: skip
    return [
        rf.write_mcap(root / "a.mcap", _messages(rf.synthetic_grasp(N_FRAMES, seed=1)) + odom),
        rf.write_mcap(root / "b.mcap", _messages(rf.synthetic_grasp(N_FRAMES, seed=2))),
        rf.write_bag(root / "c_bag", _messages(rf.synthetic_grasp(N_FRAMES, seed=3))),
    ]


def _open(path: Path) -> Memory:
    """The memory as ``tactus ingest`` opens it: the default space, the shipped touch."""
    mem = Memory.open(str(path), background=False)
    if "touch" not in mem.senses:
        mem.add_sense(TactusEncoder())
    return mem


def _rows(mem: Memory) -> dict[str, dict]:
    tbl = mem.store.scan(None, [*COLUMNS, "vector"])
    return {r["id"]: r for r in tbl.to_pylist()}


def _same_rows(a: dict[str, dict], b: dict[str, dict]) -> None:
    assert sorted(a) == sorted(b)  # the same ids
    for i, row in a.items():
        assert {c: row[c] for c in COLUMNS} == {c: b[i][c] for c in COLUMNS}, i
    va = np.array([a[i]["vector"] for i in sorted(a)], np.float32)
    vb = np.array([b[i]["vector"] for i in sorted(a)], np.float32)
    np.testing.assert_allclose(va, vb, atol=1e-5)


def _cli(*args: str) -> dict:
    from tactus_memory.cli import app

    r = CliRunner().invoke(app, list(args))
    assert r.exit_code == 0, (r.output, r.exception)
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def ingested(local_ray, recordings, tmp_path_factory) -> tuple[Path, Path, dict, dict]:
    """The same recordings ingested by the local path and by ``tactus ingest --ray``."""
    root = tmp_path_factory.mktemp("stores")
    topics = {**TOPICS, "/odom": "pose"}
    local = ingest_recording(_open(root / "local"), recordings, session="run", topics=topics)
    args = ["ingest", *map(str, recordings), "--data", str(root / "ray"), "--session", "run"]
    args += [a for t, s in topics.items() for a in ("--topic", f"{t}={s}")]
    on_ray = _cli(*args, "--json", "--ray", "--ray-workers", str(local_ray))
    return root / "local", root / "ray", local.model_dump(), on_ray


def test_ingest_on_ray_gives_the_local_rows_and_a_rerun_adds_nothing(ingested, recordings):
    local_path, ray_path, local, on_ray = ingested
    n = len(recordings) * (3 + N_FRAMES // 8)
    assert sum(local["rows"].values()) == n and local["poses"] == {"/odom": 8}
    for key in ("rows", "messages", "skipped", "existing", "poses", "t0", "topics"):
        assert on_ray[key] == local[key], key
    a, b = _rows(_open(local_path)), _rows(_open(ray_path))
    _same_rows(a, b)
    assert sum(r["placed"] == "poses" for r in b.values()) > 0  # placed from /odom
    # again, on Ray: nothing new, every item found
    mem = _open(ray_path)
    again = ingest_on_ray(mem, recordings, session="run", topics={**TOPICS, "/odom": "pose"},
                          address=LOCAL)  # fmt: skip
    assert again.rows == {} and again.existing == n
    assert len(mem) == n


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> Pair:
    return train_pair(tmp_path_factory.mktemp("pair"))


def test_reembed_on_ray_gives_the_local_vectors(ingested, pair, tmp_path) -> None:
    local_path = ingested[0]
    before = _rows(_open(local_path))
    shutil.copytree(local_path, tmp_path / "local")
    shutil.copytree(local_path, tmp_path / "ray")
    mem = _open(tmp_path / "local")
    report = mem.reembed("touch", TactusEncoder(pair.b))
    on_ray = _cli("reembed", "--checkpoint", str(pair.b), "--data", str(tmp_path / "ray"),
                  "--ray")  # fmt: skip
    assert on_ray["rows"] == report.rows == sum(r["sense"] == "touch" for r in before.values())
    assert on_ray["provenance"] == report.provenance
    assert on_ray["late"] == 0  # every vector was staged by the Ray workers, none at the swap
    a, b = _rows(_open(tmp_path / "local")), _rows(_open(tmp_path / "ray"))
    _same_rows(a, b)
    touch = sorted(i for i, r in before.items() if r["sense"] == "touch")
    old = np.array([before[i]["vector"] for i in touch])
    new = np.array([b[i]["vector"] for i in touch])
    assert not np.allclose(old, new, atol=1e-3)  # B's vectors, not A's


def test_a_sense_that_cannot_travel_is_named_before_anything_is_written(
    local_ray, recordings, tmp_path
) -> None:
    mem = make_memory(tmp_path / "m")
    mem.senses["touch"].lock = threading.Lock()  # cannot be pickled to a worker
    with pytest.raises(InvalidInputError, match="sense 'touch' cannot be sent to Ray workers"):
        ingest_on_ray(mem, recordings[:1], session="run", topics=TOPICS, address=LOCAL)
    assert len(mem) == 0


def test_the_commands_never_import_ray_without_the_flag() -> None:
    """Ray loads only for ``--ray``: every command module of ``tactus`` imports without it
    (the server: tests/project/test_architecture.py's NOT_SERVED)."""
    argv = (
        "import sys; from tactus_memory.cli import main; sys.argv = ['tactus', 'ingest', '--help']"
    )
    r = subprocess.run([sys.executable, "-X", "importtime", "-c", f"{argv}; main()"],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)  # fmt: skip
    assert r.returncode == 0 and "--ray-workers" in r.stdout, r.stderr[-3000:]
    imported = [line.rsplit("|", 1)[-1].strip() for line in r.stderr.splitlines()]
    assert "tactus_memory.cli.recording_cmds" in imported  # the import log is read
    assert [m for m in imported if m.split(".")[0] in ("ray", "lance_ray")] == []
