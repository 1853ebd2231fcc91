"""The glove ingest path's cheap checks and its priority (issue 28): a stream frame of 16-bit
sensor readings skips the checks it cannot fail, others keep them; the group committer's thread
runs at a lower priority than the requests served beside it (the server's default); the
encoder process embeds touch batches outside the server's interpreter lock."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.encode_process import EncoderProcess
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.service.app import create_app
from tactus_memory.service.arrays import MAX_FRAME_VALUE, load_npy
from tactus_memory.settings import DEFAULT_COMMIT_NICE, Settings
from tactus_memory.storage.rows import PreparedWrite, check_batch
from tactus_memory.where import DEFAULT_FRAME
from tests.helpers.service import StandInTouch, make_memory, window

linux_only = pytest.mark.skipif(sys.platform != "linux", reason="per-thread niceness is Linux's")


def npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def test_sixteen_bit_frames_load_as_float32_values() -> None:
    raw = (500 + np.arange(32 * 32).reshape(32, 32) % 200).astype(np.uint16)
    for dtype in (np.uint16, np.int16, np.uint8):
        out = load_npy(npy(raw.astype(dtype)), "frame", frames=True)
        assert out.dtype == np.float32 and np.array_equal(out, raw.astype(dtype))
    assert np.iinfo(np.uint16).max < MAX_FRAME_VALUE  # why 16-bit frames need no range check


def test_wider_and_float_frames_keep_their_checks() -> None:
    big = np.full((32, 32), int(MAX_FRAME_VALUE) * 2, np.int32)
    with pytest.raises(InvalidInputError, match="beyond"):
        load_npy(npy(big), "frame", frames=True)
    bad = np.full((32, 32), 600.0, np.float32)
    bad[3, 4] = np.nan
    with pytest.raises(InvalidInputError, match="NaN or inf"):
        load_npy(npy(bad), "frame", frames=True)


def thread_nice(tid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, tid)


@linux_only
def test_committer_thread_is_niced_and_the_caller_is_not(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem", touch=False)
    mine = thread_nice(threading.get_native_id())
    with GroupCommitter(memory, tick=0, nice=5) as gc:
        assert gc.add_many("s", "text", ["a note"], t=[0.0])  # the thread ran a commit
        assert thread_nice(gc._thread.native_id) == min(mine + 5, 19)
    assert thread_nice(threading.get_native_id()) == mine
    assert len(memory) == 1


@linux_only
def test_server_committer_takes_the_commit_nice_setting(tmp_path, monkeypatch) -> None:
    assert Settings().commit_nice == DEFAULT_COMMIT_NICE
    monkeypatch.setenv("TACTUS_COMMIT_NICE", "3")
    memory = make_memory(tmp_path / "mem", touch=False)
    mine = thread_nice(threading.get_native_id())
    app = create_app(Settings(), memory=memory)
    with TestClient(app) as c:
        assert c.post("/sessions/s/text", json={"text": "a note", "t": 0}).status_code == 201
        committer = app.state.tactus.committer
        assert committer.nice == 3
        assert thread_nice(committer._thread.native_id) == min(mine + 3, 19)
        assert c.get("/search", params={"q": "a note", "k": 1}).status_code == 200
    with pytest.raises(ValueError, match="commit_nice"):
        Settings(commit_nice=20)


# ----------------------------------------------------------------------------- encoder process
def started(ep: EncoderProcess) -> EncoderProcess:
    deadline = time.monotonic() + 180  # a spawned interpreter imports torch: slow when loaded
    while not ep.ready and time.monotonic() < deadline:
        time.sleep(0.1)
    assert ep.ready, "the encoder process did not start"
    return ep


def touch_write(sense: Any, windows: list[np.ndarray], t0: float) -> PreparedWrite:
    times = [t0 + i for i in range(len(windows))]
    batch = check_batch(len(windows), times, None, None, None, None, DEFAULT_FRAME)
    return PreparedWrite("s", sense, windows, batch, "")


def test_encoder_process_embeds_served_senses_as_the_thread_would() -> None:
    """The real touch encoder in a worker process gives the rows it gives in-thread; a sense
    it does not serve (not registered: it cannot be rebuilt there) is left to the memory;
    when the worker dies, writes are left to the memory too (embedded in-thread)."""
    from tactus_memory.adapters.touch import TactusEncoder

    enc = TactusEncoder()
    wins = [enc.validate(window(seed=s)) for s in range(3)]
    stand_in = StandInTouch(enc.dim)
    ep = started(EncoderProcess(("touch",), nice=1, threads=1))
    try:
        writes = [
            touch_write(enc, wins[:2], 0.0),
            touch_write(enc, wins[2:], 2.0),
            touch_write(stand_in, wins[:1], 3.0),
        ]
        ep.embed_writes(writes, enc.dim)
        got = np.concatenate([writes[0].vectors, writes[1].vectors])
        assert np.allclose(got, enc.embed(wins), atol=1e-5)
        assert writes[2].vectors is None
        os.kill(ep.pid, signal.SIGKILL)
        again = [touch_write(enc, wins, 5.0)]
        ep.embed_writes(again, enc.dim)
        assert again[0].vectors is None and ep.broken and not ep.ready
    finally:
        ep.close()


def test_server_with_encode_process_commits_writes(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem")  # a stand-in touch: embedded in the thread
    app = create_app(Settings(encode_process=True, commit_nice=0), memory=memory)
    with TestClient(app) as c:
        assert isinstance(app.state.tactus.committer.encoder, EncoderProcess)
        body = {"frames": window().tolist(), "t": 1.0}
        assert c.post("/sessions/g/touch", json=body).status_code == 201
    assert len(memory) == 1


PARENT = """
import sys, time
from tactus_memory.memory.encode_process import EncoderProcess
if __name__ == "__main__":
    ep = EncoderProcess(("touch",))
    while not ep.ready:
        time.sleep(0.1)
    print(ep.pid, flush=True)
    time.sleep(600)
"""


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@linux_only
def test_encoder_process_ends_with_a_killed_server(tmp_path) -> None:
    """A server SIGKILLed (no shutdown hook runs) leaves no encoder process behind."""
    script = tmp_path / "server.py"
    script.write_text(PARENT)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(proc.stdout.readline())
        assert alive(worker)
    finally:
        proc.kill()
        proc.wait(30)
    deadline = time.monotonic() + 30
    while alive(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(worker)
