"""Recordings in and out on real files: MCAP (mcap-ros2-support writer), ROS 2 bags (rosbags
writer, sqlite3 and mcap storage), Rerun .rrd read back with rerun's own reader. A fake text
space and a stand-in touch sense keep these fast; tests/recordings/test_recordings_real.py runs
MiniLM,
the shipped TactusEncoder and real STAG frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactus_memory.errors import RecordingError, UnknownSenseError
from tactus_memory.recordings import samples as rf
from tactus_memory.recordings.ingest import ingest_recording, list_topics, topic_source
from tactus_memory.recordings.rerun import export_rerun
from tactus_memory.touch.windows import cut_windows
from tests.helpers.fakes import HashingSpace
from tests.helpers.recording_files import N_FRAMES, NOTES, START, TOPICS, _messages
from tests.helpers.service import make_memory


@pytest.fixture(params=["mcap", "bag-sqlite3", "bag-mcap"])
def recording(request, tmp_path) -> Path:
    msgs = _messages()
    if request.param == "mcap":
        return rf.write_mcap(tmp_path / "run.mcap", msgs)
    return rf.write_bag(tmp_path / "run_bag", msgs, storage=request.param.split("-")[1])


def test_list_topics_types_counts_and_default_senses(recording: Path) -> None:
    rows = {r.topic: r for r in list_topics(recording)}
    assert rows["/glove/pressure"].type == "sensor_msgs/msg/Image"
    assert rows["/glove/pressure"].count == N_FRAMES
    assert rows["/glove/pressure"].sense == "touch"  # mono16 -> touch
    assert (rows["/notes"].count, rows["/notes"].sense) == (3, "text")
    assert (rows["/camera"].sense, rows["/imu"].sense) == ("image", None)
    assert rows["/imu"].type == "geometry_msgs/msg/Vector3"


def test_ingest_rows_times_windows_and_rerun_adds_nothing(recording: Path, tmp_path) -> None:
    mem = make_memory(tmp_path / "mem")
    s = ingest_recording(mem, recording, session="run1", topics=TOPICS)
    assert s.rows == {"text": 3, "touch": N_FRAMES // 8}
    assert s.messages == N_FRAMES + 3 and s.existing == 0
    assert s.skipped == {"touch: frames after the last full window": N_FRAMES % 8}
    # the clock starts at the earliest mapped message: the first glove frame (/imu is unmapped)
    assert s.t0 == pytest.approx(START / rf.NS + 0.5)
    items = mem.timeline("run1")
    notes = [it for it in items if it.sense == "text"]
    assert [n.text for n in notes] == NOTES
    assert [n.t for n in notes] == pytest.approx([0.5, 1.5, 2.5])  # session clock
    assert {n.source for n in notes} == {"notes"}
    touch = [it for it in items if it.sense == "touch"]
    assert touch[0].source == "glove.pressure" and touch[0].meta["topic"] == "/glove/pressure"
    assert touch[0].t == pytest.approx(0.0)
    assert touch[0].t_end == pytest.approx(7 / 30, abs=1e-6)  # 8 frames at 30 Hz
    # the same windows the library's stream windowing cuts from the frames
    frames = rf.synthetic_grasp(N_FRAMES)
    want = cut_windows(frames, np.arange(N_FRAMES) / 30, window=8, stride=8)
    got = [mem.get_item(it.id).raw for it in touch]
    stored = np.stack(got)  # float16 calibrated by the stand-in: raw values kept
    assert np.allclose(stored, want.frames, rtol=2e-3)
    assert [it.t for it in touch] == pytest.approx(want.t.tolist())
    # twice: nothing new, same count
    n = len(mem)
    again = ingest_recording(mem, recording, session="run1", topics=TOPICS)
    assert again.rows == {} and again.existing == 3 + N_FRAMES // 8
    assert len(mem) == n


def test_interrupted_ingest_resumes(tmp_path, monkeypatch) -> None:
    """A crash after some commits keeps them; the next run adds exactly the rest."""
    path = rf.write_mcap(tmp_path / "run.mcap", _messages())
    mem = make_memory(tmp_path / "mem")
    real_add_many = mem.add_many
    calls = {"n": 0}

    def flaky(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # the process is stopped mid-ingest
        return real_add_many(*a, **kw)

    monkeypatch.setattr(mem, "add_many", flaky)
    with pytest.raises(KeyboardInterrupt):
        ingest_recording(mem, path, session="run1", topics=TOPICS, batch=4)
    first = len(mem)
    assert 0 < first < 3 + N_FRAMES // 8
    monkeypatch.setattr(mem, "add_many", real_add_many)
    s = ingest_recording(mem, path, session="run1", topics=TOPICS, batch=4)
    assert s.existing == first
    assert sum(s.rows.values()) == 3 + N_FRAMES // 8 - first
    assert len(mem) == 3 + N_FRAMES // 8


def test_unsupported_topic_is_named(tmp_path) -> None:
    path = rf.write_mcap(tmp_path / "run.mcap", _messages())
    mem = make_memory(tmp_path / "mem")
    with pytest.raises(RecordingError, match=r"'/imu'.*geometry_msgs/msg/Vector3.*touch"):
        ingest_recording(mem, path, session="s", topics={"/imu": "touch", "/notes": "text"})
    assert len(mem) == 0  # checked before anything is written
    with pytest.raises(RecordingError, match="'/nope' is in none of the files"):
        ingest_recording(mem, path, session="s", topics={"/nope": "text"})
    with pytest.raises(UnknownSenseError, match="'smell'"):
        ingest_recording(mem, path, session="s", topics={"/notes": "smell"})
    with pytest.raises(RecordingError, match="cannot become text"):
        ingest_recording(mem, path, session="s", topics={"/glove/pressure": "text"})


def test_images_skipped_without_vision(tmp_path) -> None:
    path = rf.write_bag(tmp_path / "bag", _messages())
    mem = make_memory(tmp_path / "mem")
    s = ingest_recording(mem, path, session="s", topics={"/camera": "image", "/notes": "text"})
    assert s.rows == {"text": 3}
    assert s.skipped == {"image: space 'fake-hash' has no vision, images not stored": 1}


@pytest.mark.parametrize("kind", ["garbage", "truncated", "empty-bag-folder"])
def test_corrupt_file_is_a_clear_error(tmp_path, kind: str) -> None:
    mem = make_memory(tmp_path / "mem")
    if kind == "garbage":
        path = tmp_path / "x.mcap"
        path.write_bytes(b"this is not an mcap file at all" * 10)
    elif kind == "truncated":
        good = rf.write_mcap(tmp_path / "good.mcap", _messages()).read_bytes()
        path = tmp_path / "cut.mcap"
        path.write_bytes(good[: len(good) // 2])
    else:
        path = tmp_path / "bag"
        path.mkdir()
        (path / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    with pytest.raises(RecordingError, match=str(path.name)):
        ingest_recording(mem, path, session="s", topics=TOPICS)


def test_int16_multiarray_and_unstamped_frames_use_log_time(tmp_path) -> None:
    frames = rf.synthetic_grasp(16, seed=3)
    msgs = [rf.int16_array("/taxels", START + i * rf.NS // 30, f) for i, f in enumerate(frames)]
    msgs += rf.glove("/glove", frames, start_ns=START + 10 * rf.NS, stamped=False)
    path = rf.write_bag(tmp_path / "bag", msgs, storage="mcap")
    mem = make_memory(tmp_path / "mem")
    s = ingest_recording(
        mem, path, session="s", topics={"/taxels": "touch", "/glove": "touch"}, absolute=True
    )
    assert s.rows == {"touch": 4} and s.t0 is None
    items = mem.timeline("s")
    assert [it.source for it in items] == ["taxels", "taxels", "glove", "glove"]
    assert items[0].t == pytest.approx(START / rf.NS)  # --absolute: unix seconds
    assert items[2].t == pytest.approx(START / rf.NS + 10)  # no header stamp: log time
    assert np.allclose(mem.get_item(items[0].id).raw, frames[:8], rtol=2e-3)


def test_topic_source_ids() -> None:
    assert topic_source("/glove/left/pressure") == "glove.left.pressure"
    assert topic_source("/~weird{x}") == "weird_x_"


def test_export_rerun_reads_back(tmp_path) -> None:
    from rerun.chunk import RrdReader

    path = rf.write_mcap(tmp_path / "run.mcap", _messages())
    mem = make_memory(tmp_path / "mem")
    ingest_recording(mem, path, session="run1", topics=TOPICS)
    out = export_rerun(mem, "run1", tmp_path / "out" / "run1.rrd", query="picked up the red mug")
    assert out.entities["touch/glove.pressure"] == N_FRAMES // 8
    assert out.entities["text/notes"] == 3
    assert out.moments >= 1
    chunks = RrdReader(out.path).stream().to_chunks()
    by: dict[str, list] = {}
    for c in chunks:
        by.setdefault(c.entity_path, []).append(c.to_record_batch().to_pydict())
    texts = [t[0] for b in by["/text/notes"] for t in b["TextLog:text"]]
    assert sorted(texts) == sorted(NOTES)
    times = sorted(
        x.total_seconds() for b in by["/touch/glove.pressure"] for x in b["session_time"]
    )
    assert times == pytest.approx([8 * i / 30 for i in range(N_FRAMES // 8)], abs=1e-6)
    image_rows = sum(len(b["Image:buffer"]) for b in by["/touch/glove.pressure"])
    assert image_rows == N_FRAMES // 8
    moments = [t[0] for b in by["/moments/query"] for t in b["TextLog:text"]]
    assert any("picked up the red mug" in m for m in moments)


def test_export_skips_times_rerun_cannot_hold(tmp_path) -> None:
    """Found by schemathesis: a note at t=1e300 made the export a 500 (OverflowError in Rerun's
    int64 nanoseconds); times are now at most MAX_SECONDS (1e10 s), still beyond Rerun's 9.2e9:
    such a note is skipped, with why."""
    mem = make_memory(tmp_path / "mem")
    mem.add("far", "text", "a note from the far future", t=9.9e9)
    mem.add("far", "text", "a note from now", t=3.0)
    out = export_rerun(mem, "far", tmp_path / "far.rrd")
    assert out.entities == {"text/text": 1}
    assert list(out.skipped.values()) == [1] and "Rerun" in next(iter(out.skipped))


class VisionHashingSpace(HashingSpace):
    """The hashing text space plus a toy vision tower (mean colour -> a fixed projection)."""

    has_vision = True

    def embed_images(self, images):
        rng = np.random.default_rng(1)
        proj = rng.standard_normal((3, self.dim)).astype(np.float32)
        means = np.stack([np.asarray(im, np.float32).reshape(-1, 3).mean(0) + 1 for im in images])
        out = means @ proj
        return out / np.linalg.norm(out, axis=1, keepdims=True)


def test_images_stored_with_a_vision_space(tmp_path) -> None:
    from tactus_memory.adapters.image import ImageSense
    from tactus_memory.memory.main import Memory

    mem = Memory.open(str(tmp_path / "mem"), space=VisionHashingSpace())
    mem.add_sense(ImageSense(mem.space))
    picture = np.zeros((6, 8, 3), np.uint8)
    picture[..., 0] = 200  # red in RGB
    msgs = [rf.rgb8("/camera", START + i * rf.NS, picture) for i in range(3)]
    path = rf.write_mcap(tmp_path / "cam.mcap", msgs)
    s = ingest_recording(mem, path, session="cam", topics={"/camera": "image"})
    assert s.rows == {"image": 3} and s.skipped == {}
    items = mem.timeline("cam")
    assert [it.t for it in items] == pytest.approx([0.0, 1.0, 2.0])
    assert [it.source for it in items] == ["camera"] * 3


def _ns(**kw):
    from types import SimpleNamespace

    return SimpleNamespace(**kw)


def test_decode_touch_encodings() -> None:
    from tactus_memory.adapters import decode

    frame = np.arange(1024, dtype=np.uint16).reshape(32, 32) + 500
    padded = np.zeros((32, 40), ">u2")  # big-endian rows padded to a 80-byte step
    padded[:, :32] = frame
    msg = _ns(height=32, width=32, step=80, encoding="16UC1", is_bigendian=1,
              data=padded.tobytes())  # fmt: skip
    got = decode.touch_frame(msg, decode.IMAGE, (32, 32), "t")
    assert np.array_equal(got, frame) and got.dtype.isnative
    mono8 = _ns(height=32, width=32, step=32, encoding="mono8", is_bigendian=0,
                data=np.full(1024, 255, np.uint8).tobytes())  # fmt: skip
    assert np.allclose(decode.touch_frame(mono8, decode.IMAGE, (32, 32), "t"), 1.0)
    f32 = _ns(height=32, width=32, step=128, encoding="32FC1", is_bigendian=0,
              data=np.full(1024, 0.25, "<f4").tobytes())  # fmt: skip
    assert np.allclose(decode.touch_frame(f32, decode.IMAGE, (32, 32), "t"), 0.25)
    arr = _ns(data=[0.5] * 1024)
    got = decode.touch_frame(arr, "std_msgs/msg/Float32MultiArray", (32, 32), "t")
    assert got.shape == (32, 32) and np.allclose(got, 0.5)
    with pytest.raises(RecordingError, match="holds 10 values"):
        decode.touch_frame(_ns(data=[1] * 10), "std_msgs/msg/Int16MultiArray", (32, 32), "w")
    small = _ns(height=16, width=16, step=32, encoding="mono16", is_bigendian=0,
                data=bytes(512))  # fmt: skip
    with pytest.raises(RecordingError, match=r"\(16, 16\), the sense takes \(32, 32\)"):
        decode.touch_frame(small, decode.IMAGE, (32, 32), "w")
    rgb = _ns(height=2, width=2, step=6, encoding="rgb8", is_bigendian=0, data=bytes(12))
    with pytest.raises(RecordingError, match="'rgb8' is not single-channel"):
        decode.touch_frame(rgb, decode.IMAGE, (32, 32), "w")


def test_decode_camera_images() -> None:
    import io

    from PIL import Image

    from tactus_memory.adapters import decode

    px = np.zeros((2, 3, 3), np.uint8)
    px[..., 2] = 255  # blue in RGB
    bgr = _ns(height=2, width=3, step=9, encoding="bgr8", is_bigendian=0,
              data=px[..., ::-1].tobytes())  # fmt: skip
    assert np.array_equal(decode.camera_image(bgr, decode.IMAGE, "c"), px)
    buf = io.BytesIO()
    Image.fromarray(px).save(buf, format="PNG")
    png = _ns(format="png", data=buf.getvalue())
    assert np.array_equal(decode.camera_image(png, decode.COMPRESSED, "c"), px)
    with pytest.raises(RecordingError, match="cannot be decoded"):
        decode.camera_image(_ns(format="jpeg", data=b"nope"), decode.COMPRESSED, "c")


def test_exported_heat_map_is_the_page_renderer(tmp_path) -> None:
    """The .rrd image of a window is exactly render.window_rgba's picture of the stored window."""
    from rerun.chunk import RrdReader

    from tactus_memory.recordings.rerun import EXPORT_SCALE
    from tactus_memory.touch.render import window_rgba

    path = rf.write_mcap(tmp_path / "run.mcap", _messages())
    mem = make_memory(tmp_path / "mem")
    ingest_recording(mem, path, session="run1", topics={"/glove/pressure": "touch"})
    first = mem.timeline("run1")[0]
    want = window_rgba(mem.get_item(first.id).raw, scale=EXPORT_SCALE)  # (H, W, 4) uint8
    out = export_rerun(mem, "run1", tmp_path / "run1.rrd")
    rows = []
    for c in RrdReader(out.path).stream().to_chunks():
        if c.entity_path == "/touch/glove.pressure":
            b = c.to_record_batch().to_pydict()
            rows += list(zip(b["session_time"], b["Image:buffer"], strict=True))
    t, buffer = min(rows, key=lambda r: r[0])
    assert t.total_seconds() == pytest.approx(first.t)
    got = np.frombuffer(bytes(np.asarray(buffer[0], np.uint8)), np.uint8)
    assert np.array_equal(got, want.reshape(-1))


@pytest.mark.parametrize("writer", ["mcap", "bag"])
def test_refused_windows_are_skipped_with_their_reason(tmp_path, writer: str) -> None:
    frames = rf.synthetic_grasp(24, seed=5).astype(np.float32)
    frames[10, 3, 3] = np.nan  # window 1 (frames 8-15) is refused by the sense
    msgs = [rf.float32_array("/taxels", START + i * rf.NS // 30, f) for i, f in enumerate(frames)]
    if writer == "mcap":
        path = rf.write_mcap(tmp_path / "f.mcap", msgs)
    else:
        path = rf.write_bag(tmp_path / "bag", msgs)
    mem = make_memory(tmp_path / "mem")
    s = ingest_recording(mem, path, session="s", topics={"/taxels": "touch"})
    assert s.rows == {"touch": 2}
    assert s.skipped == {"touch: refused, InvalidInputError: touch window contains NaN or inf": 1}
    assert [it.t for it in mem.timeline("s")] == pytest.approx([0.0, 16 / 30])


def test_a_recordings_stamps_fit_the_time_rule(tmp_path) -> None:
    """Issue 48: a recording's stamps are int64 nanoseconds, so the largest one a file can
    hold (2**63 - 1 ns, 9.2e9 s) is within the time rule's range (|t| <= 1e10 s): it is
    stored in seconds, and search answers beside it."""
    from tactus_memory.limits import MAX_SECONDS

    last = 2**63 - 1
    notes = [rf.note("/notes", 1, "the first note"), rf.note("/notes", last, "the last note")]
    path = rf.write_mcap(tmp_path / "far.mcap", notes)
    mem = make_memory(tmp_path / "mem")
    ingest_recording(mem, path, session="far", topics={"/notes": "text"})
    first, far = mem.timeline("far")
    assert far.t - first.t == pytest.approx((last - 1) / 1e9) and abs(far.t) <= MAX_SECONDS
    assert mem.search("the last note", 1)[0].id == far.id
