"""The glove ingest path's cheap checks and its priority (issue 28): a stream frame of 16-bit
sensor readings skips the checks it cannot fail, others keep them; the group committer's thread
runs at a lower priority than the requests served beside it (the server's default)."""

from __future__ import annotations

import io
import os
import sys
import threading

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import InvalidInputError
from tactus_memory.group_commit import GroupCommitter
from tactus_memory.service.app import create_app
from tactus_memory.service.arrays import MAX_FRAME_VALUE, load_npy
from tactus_memory.settings import DEFAULT_COMMIT_NICE, Settings
from tests.test_service_helpers import make_memory

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
