"""Recordings on the real path: real STAG glove frames as mono16 Images at 30 Hz in a real
MCAP file and a real ROS 2 bag, the real MiniLM space, the shipped TactusEncoder, plain-language
search, re-ingest, a .rrd read back with rerun, the CLI, and the HTTP export on a real uvicorn.

The frames come from the ``weights`` recordings of the mug and the tape, which are in the
shipped checkpoint's training data: this checks the ingest path end to end (the right frames,
windows, times and vectors reach the memory), not how well touch generalises.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.memory.main import Memory
from tactus_memory.recordings import samples as rf
from tactus_memory.recordings.ingest import ingest_recording
from tactus_memory.recordings.rerun import export_rerun
from tactus_memory.touch.windows import cut_windows
from tests.helpers.progress import assert_bar_finished

pytestmark = pytest.mark.slow

START = 1_750_000_000 * rf.NS
PER_OBJECT = 96  # 3.2 s of glove frames at 30 Hz per object, from its first grasp frame
NOTES = [(1.0, "put the mug on the top shelf"), (4.5, "sealed the cardboard box with tape")]
TOPICS = {"/notes": "text", "/glove/pressure": "touch"}


@pytest.fixture(scope="module")
def glove_frames(stag_dir: Path) -> np.ndarray:
    """(192, 32, 32) int16 raw: 96 frames of the mug recording, then 96 of the tape."""
    from tactus_memory.training.data import load_stag

    data = load_stag(stag_dir / "weights_lite" / "metadata.mat")
    parts = []
    for name in ("mug", "tape"):
        oid = data.objects.index(name)
        first = int(np.flatnonzero((data.object_id == oid) & data.valid)[0])
        parts.append(data.pressure[first : first + PER_OBJECT])
    return np.concatenate(parts)


def _messages(frames: np.ndarray) -> list[rf.Msg]:
    msgs = rf.glove("/glove/pressure", frames, start_ns=START)
    msgs += [rf.note("/notes", START + round(t * rf.NS), text) for t, text in NOTES]
    msgs.append(rf.vector3("/imu", START))
    return msgs


@pytest.fixture(scope="module")
def encoder():
    from tactus_memory.adapters.touch import TactusEncoder

    return TactusEncoder()


@pytest.fixture
def real_memory(tmp_path, minilm_space, encoder) -> Memory:
    mem = Memory.open(str(tmp_path / "mem"), space=minilm_space)
    mem.add_sense(encoder)
    return mem


@pytest.mark.parametrize("kind", ["mcap", "bag-sqlite3"])
def test_real_glove_recording_in_plain_language(
    kind: str, tmp_path, glove_frames, real_memory: Memory, encoder
) -> None:
    msgs = _messages(glove_frames)
    if kind == "mcap":
        path = rf.write_mcap(tmp_path / "glove.mcap", msgs)
    else:
        path = rf.write_bag(tmp_path / "glove_bag", msgs, storage="sqlite3")
    mem = real_memory
    s = ingest_recording(mem, path, session="kitchen", topics=TOPICS)
    # the stream windowing's cut; its idle windows (no contact) are skipped, not embedded
    want = cut_windows(glove_frames, np.arange(len(glove_frames)) / 30, window=8, stride=8)
    n_idle = int(want.idle.sum())
    assert len(want) == 2 * PER_OBJECT // 8 and 0 < n_idle < len(want) // 2
    n_windows = len(want) - n_idle
    assert s.rows == {"text": 2, "touch": n_windows}
    assert s.skipped == {"touch: idle window (no contact)": n_idle}
    want = want.take(~want.idle)
    # the stored touch vectors are the encoder's vectors of the stream-windowed frames
    touch = [it for it in mem.timeline("kitchen") if it.sense == "touch"]
    got = np.stack([mem.get_item(it.id, vector=True).vector for it in touch])
    assert np.allclose(got, encoder.embed(want.frames), atol=1e-4)
    # plain language: the note and the touch of the mug
    note = mem.search("where did the mug go?", k=1, senses=["text"], session="kitchen")[0]
    assert note.text == NOTES[0][1] and note.t == pytest.approx(1.0)
    mug = mem.search("holding a mug", k=3, senses=["touch"], session="kitchen")
    assert mug and all(h.source == "glove.pressure" for h in mug)
    assert mug[0].t < PER_OBJECT / 30  # the best touch match lies in the mug's part
    tape = mem.search("holding a roll of tape", k=1, senses=["touch"], session="kitchen")[0]
    assert tape.t >= PER_OBJECT / 30  # ... and the tape's in the tape's part
    # twice: nothing added
    n = len(mem)
    again = ingest_recording(mem, path, session="kitchen", topics=TOPICS)
    assert again.rows == {} and again.existing == 2 + n_windows and len(mem) == n
    # out to Rerun, moments of the query annotated
    from rerun.chunk import RrdReader

    out = export_rerun(mem, "kitchen", tmp_path / "kitchen.rrd", query="holding a mug")
    assert out.entities["touch/glove.pressure"] == n_windows and out.moments >= 1
    paths = {c.entity_path for c in RrdReader(out.path).stream().to_chunks()}
    assert {"/touch/glove.pressure", "/text/notes", "/moments/query"} <= paths


def test_real_cli_and_http_export(tmp_path, glove_frames, minilm_space) -> None:
    from rerun.chunk import RrdReader

    from tactus_memory.cli.app import app
    from tests.helpers.servers import Server

    path = rf.write_bag(tmp_path / "bag", _messages(glove_frames), storage="mcap")
    data = tmp_path / "mem"
    runner = CliRunner()
    cut = cut_windows(glove_frames, np.arange(len(glove_frames)) / 30, window=8, stride=8)
    n_touch = int((~cut.idle).sum())  # idle windows (no contact) are not stored
    listed = runner.invoke(app, ["ingest", str(path), "--list"])
    assert listed.exit_code == 0 and "/glove/pressure" in listed.output and "touch" in listed.output
    cmd = ["ingest", str(path), "--session", "run1", "--data", str(data)]
    cmd += ["--topic", "/notes=text", "--topic", "/glove/pressure=touch"]
    first = runner.invoke(app, [*cmd, "--json"])
    assert first.exit_code == 0, first.output
    summary = json.loads(first.output)
    assert summary["rows"] == {"text": 2, "touch": n_touch}
    assert summary["messages_per_s"] > 0
    second = runner.invoke(app, cmd)
    assert second.exit_code == 0 and f"already present {2 + n_touch}" in second.output
    assert_bar_finished(second.stderr, "ingest run1")  # the messages read, with the time left
    bad = runner.invoke(app, [*cmd[:6], "--topic", "/imu=touch"])
    assert bad.exit_code == 2 and "'/imu'" in bad.output and "Vector3" in bad.output
    rrd = tmp_path / "run1.rrd"
    exported = runner.invoke(
        app, ["export", "rerun", "run1", "--out", str(rrd), "--data", str(data)]
    )
    assert exported.exit_code == 0, exported.output
    assert f"touch/glove.pressure {n_touch}" in exported.output

    server = Server(data, tmp_path / "server.log")
    try:
        r = httpx.get(
            f"{server.base}/sessions/run1/export.rrd", params={"q": "holding a mug"}, timeout=120
        )
        assert r.status_code == 200, r.text
        assert "run1.rrd" in r.headers["content-disposition"]
        got = tmp_path / "http.rrd"
        got.write_bytes(r.content)
        chunks = RrdReader(got).stream().to_chunks()
        notes = [
            t[0]
            for c in chunks
            if c.entity_path == "/text/notes"
            for t in c.to_record_batch().to_pydict()["TextLog:text"]
        ]
        assert sorted(notes) == sorted(text for _, text in NOTES)
        assert any(c.entity_path == "/moments/query" for c in chunks)
        missing = httpx.get(f"{server.base}/sessions/nope/export.rrd", timeout=30)
        assert missing.status_code == 404
        assert missing.headers["content-type"].startswith("application/problem+json")
    finally:
        server.stop()
