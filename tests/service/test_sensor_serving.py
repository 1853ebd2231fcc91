"""Serving any sensor shape (issue 35), on the real path: two touch senses beside each other,
a 16x16 skin and a five-pad robot hand assembled into one 12x16 frame
(``tests/helpers/sensors.py``),
each a tactus-tiny checkpoint trained here with the library's loop on the real STAG
blindfolded file converted to that sensor. Real MiniLM, real LanceDB, a real uvicorn
``tactus serve --touch skin=CKPT --touch hand=CKPT``: JSON and ``.npy`` writes, the WebSocket,
an ingested MCAP recording (Float32MultiArray with layout dims, mono16 and mono8 images),
search by text and by example, a taught label, heat maps, and the wrong-shape 4xx.

The checkpoints are trained on the file the stored windows come from: these tests check the
serving path for any shape, not how well a 150-step model generalises (``tactus eval`` does).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import httpx
import numpy as np
import pytest

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.client.main import Client
from tactus_memory.errors import RecordingError
from tactus_memory.memory.main import Memory
from tactus_memory.recordings import samples as rf
from tactus_memory.recordings.ingest import ingest_recording
from tactus_memory.touch.render import LEGEND_PX, SCALE
from tactus_memory.touch.windows import window_idle
from tests.helpers.browser import png_size
from tests.helpers.sensors import (  # noqa: F401  (fixtures)
    CONVERT,
    HAND,
    PROFILES,
    SKIN,
    Windows,
    hand,
    session_checkpoint,
    skin,
)
from tests.helpers.servers import Server

pytestmark = pytest.mark.slow

TOKEN = "s3ns0r"
HZ = 30.0  # frame rate of the written recording (rf.GLOVE_HZ)
KETTLE = "when was I holding the kettle?"  # no STAG object: only teaching can answer it


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory, stag, minilm_space) -> dict[str, Path]:
    """Trained once per session (the hand also serves tests/service/test_sensor_browser.py)."""
    return {
        name: session_checkpoint(tmp_path_factory, name, stag, minilm_space)
        for name in ("skin", "hand")
    }


def _above_chance(found: dict[str, str]) -> tuple[float, float]:
    """Top-1 accuracy of ``{queried object: object of the top hit}`` and chance (1 / objects)."""
    hits = sum(q == got for q, got in found.items())
    return hits / len(found), 1.0 / len(found)


# ---------------------------------------------------------------------------- recordings
def _recording(tmp_path: Path, w: Windows) -> Path:
    """Every window's 8 frames, one after another at 30 Hz, on three topics: the skin as a
    Float32MultiArray (layout 16x16), the hand as mono16 (raw) and as mono8 (calibrated x 255)."""
    msgs = []
    skin_frames = w.of("skin").reshape(-1, *SKIN.shape)
    hand_frames = w.of("hand").reshape(-1, *HAND.shape)
    for i, (sf, hf) in enumerate(zip(skin_frames, hand_frames, strict=True)):
        ns = round(i * rf.NS / HZ) + rf.NS
        msgs.append(rf.float32_array("/skin", ns, sf))
        msgs.append(rf.mono16("/hand", ns, hf, ns))
        mono8 = np.rint(HAND.scale(hf) * 255).astype(np.uint8)
        msgs.append(rf.Msg("/hand8", rf.IMAGE, ns, {
            "header": rf._header(ns), "height": 12, "width": 16, "encoding": "mono8",
            "is_bigendian": 0, "step": 16, "data": mono8.tobytes(),
        }))  # fmt: skip
    return rf.write_mcap(tmp_path / "hand.mcap", msgs)


def test_a_recording_of_each_sensor_goes_into_its_sense(
    tmp_path, checkpoints, windows, minilm_space
):
    path = _recording(tmp_path, windows)
    n = len(windows.frames)
    with Memory.open(str(tmp_path / "m"), space=minilm_space, background=False) as mem:
        for name, ck in checkpoints.items():
            mem.add_sense(TactusEncoder(ck, name=name))
        topics = {"/skin": "skin", "/hand": "hand", "/hand8": "hand"}
        summary = ingest_recording(mem, path, session="rec", topics=topics)
        # mono8 carries 1/255 steps: a taxel right at the contact level may round below it,
        # and the sense's idle rule then refuses that window (counted in skipped)
        hands = HAND.scale(windows.of("hand"))
        n8 = sum(not window_idle(np.rint(h * 255) / 255) for h in hands)
        assert summary.rows == {"skin": n, "hand": n + n8}, summary
        assert sum(summary.skipped.values()) == n - n8
        items = mem.timeline("rec")
        shapes = {(it.sense, mem.get_item(it.id).raw.shape) for it in items[:: max(1, n // 4)]}
        assert shapes <= {("skin", (8, 16, 16)), ("hand", (8, 12, 16))} and len(shapes) == 2
        # window i of the recording starts at frame 8 i: its time names its object
        start = min(it.t for it in items)
        assert start == 0.0  # the session clock starts at the first mapped message
        for name in ("skin", "hand"):
            found = {}
            for obj in sorted(set(windows.obj)):
                top = mem.search(f"a hand holding a {obj.replace('_', ' ')}", k=1,
                                 senses=[name], session="rec", group="window")[0]  # fmt: skip
                found[obj] = windows.obj[round(top.t * HZ) // 8]
            acc, chance = _above_chance(found)
            assert acc > 2 * chance, (name, found)
        # a MultiArray whose layout is another sensor's shape is named, never reshaped
        with pytest.raises(RecordingError, match=r"layout is 16x16.*reads 12x16 frames"):
            ingest_recording(mem, path, session="rec2", topics={"/skin": "hand"})


# ---------------------------------------------------------------------------- the server
def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def _store(c: httpx.Client, w: Windows, name: str, session: str, idx: np.ndarray, form: str):
    """Store windows ``idx`` of ``name`` in ``session`` with t = the window's index."""
    raw = w.of(name, idx)
    t = [float(i) for i in idx]
    url = f"/sessions/{session}/touch"
    if form == "json":
        r = c.post(url, params={"sense": name}, json={"windows": raw.tolist(), "t": t})
    else:
        r = c.post(url, params={"sense": name, "t": t}, content=_npy(raw),
                   headers={"content-type": "application/x-npy"})  # fmt: skip
    assert r.status_code == 201, r.text
    assert r.json()["count"] == len(idx) and not r.json()["skipped"]
    return r.json()["ids"]


def _problem(r: httpx.Response, status: int, *words: str) -> None:
    assert r.status_code == status, r.text
    for word in words:
        assert word in r.json()["detail"], r.json()["detail"]


def _stream(port: int, w: Windows, idx: list[int]) -> list[dict]:
    """The hand's windows ``idx`` over the WebSocket as one binary (16, 12, 16) message, after a
    glove frame the hand sense refuses."""
    from websockets.sync.client import connect

    url = (f"ws://127.0.0.1:{port}/sessions/live/touch/stream?sense=hand&window=8&stride=8"
           f"&hz={HZ}&t0=500&token={TOKEN}")  # fmt: skip
    with connect(url, open_timeout=30) as ws:
        ready = json.loads(ws.recv(timeout=30))
        assert ready["type"] == "ready" and ready["sense"] == "hand"
        assert ready["shape"] == [12, 16]
        ws.send(_npy(w.frames[0, 0]))  # (32, 32): a glove frame, not the hand's
        ws.send(_npy(w.of("hand", idx).reshape(-1, *HAND.shape)))
        return [json.loads(ws.recv(timeout=60)) for _ in range(1 + len(idx))]


def test_two_sensors_served_side_by_side(tmp_path, checkpoints, windows):
    w = windows
    lesson, day = np.flatnonzero(w.lesson), np.flatnonzero(~w.lesson)
    server = Server(tmp_path / "memory", tmp_path / "server.log", "--token", TOKEN,
                    "--touch", f"skin={checkpoints['skin']}",
                    "--touch", f"hand={checkpoints['hand']}")  # fmt: skip
    auth = {"Authorization": f"Bearer {TOKEN}"}
    try:
        with httpx.Client(base_url=server.base, headers=auth, timeout=120) as c:
            senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
            assert senses["touch"]["shape"] == [32, 32]
            assert senses["skin"]["shape"] == [16, 16] and senses["hand"]["shape"] == [12, 16]
            assert senses["text"]["shape"] is None
            assert "mug" in senses["hand"]["classes"] and senses["hand"]["taught"] == []

            # JSON and .npy bodies, each sense its own shape
            skin_ids = _store(c, w, "skin", "lesson", lesson, "json")
            skin_ids += _store(c, w, "skin", "day", day, "npy")
            hand_ids = _store(c, w, "hand", "lesson", lesson, "npy")
            hand_ids += _store(c, w, "hand", "day", day, "json")

            # a window of another sensor's shape, an unknown sense, a sense that is not touch
            glove = w.frames[:1]
            r = c.post("/sessions/x/touch", params={"sense": "skin"},
                       json={"frames": glove[0].tolist(), "t": 0.0})  # fmt: skip
            _problem(r, 422, "(8, 32, 32)", "(K, 16, 16)", "'skin'")
            r = c.post("/sessions/x/touch", params={"sense": "skin", "t": 0.0},
                       content=_npy(w.of("hand", [0])),
                       headers={"content-type": "application/x-npy"})  # fmt: skip
            _problem(r, 422, "(1, 8, 12, 16)", "(K, 16, 16)", "(B, K, 16, 16)")
            r = c.post("/sessions/x/touch", json={"frames": w.of("skin", [0])[0].tolist(),
                                                   "t": 0.0})  # fmt: skip
            _problem(r, 422, "(8, 16, 16)", "(K, 32, 32)")  # the glove is the default
            r = c.post("/sessions/x/touch", params={"sense": "insole"},
                       json={"frames": glove[0].tolist(), "t": 0.0})  # fmt: skip
            _problem(r, 404, "'insole'", "hand", "skin")
            r = c.post("/sessions/x/touch", params={"sense": "text"},
                       json={"frames": glove[0].tolist(), "t": 0.0})  # fmt: skip
            _problem(r, 422, "'text' is a text sense")

            # by text: a trained class's query finds its object above chance, per sense
            for name in ("skin", "hand"):
                found = {}
                for obj in sorted(set(w.obj)):
                    q = f"a hand holding a {obj.replace('_', ' ')}"
                    params = {"q": q, "k": 1, "sense": name, "group": "window"}
                    hits = c.get("/search", params=params).json()["hits"]
                    assert hits and hits[0]["sense"] == name, hits
                    found[obj] = w.obj[int(hits[0]["t"])]  # t = the window's index
                acc, chance = _above_chance(found)
                assert acc > 2 * chance, (name, found)

            # the WebSocket: the glove frame is refused naming both shapes, the hand's stored
            msgs = _stream(server.port, w, [int(day[0]), int(day[1])])
            errors = [m for m in msgs if m["type"] == "error"]
            assert len(errors) == 1 and "(32, 32)" in errors[0]["error"]["detail"]
            assert "(12, 16)" in errors[0]["error"]["detail"]
            stored = [m for m in msgs if m["type"] == "stored"]
            assert [m["t"] for m in stored] == [
                pytest.approx(500 + 1 / HZ),
                pytest.approx(500 + 9 / HZ),
            ]
            live = c.get(f"/items/{stored[0]['id']}/touch.json").json()
            assert np.array(live["values"]).shape == (8, 12, 16)
            assert c.get("/sessions/live").json()["counts"] == {"hand": 2}

            # the Client: a touch sense of another sensor goes to the touch route, by name
            client = Client(server.base, token=TOKEN)
            got = client.add_many("cl", "skin", list(w.of("skin", day[:2])), t=[1.0, 2.0])
            assert len(got) == 2
            with client.stream_touch("cl", sense="hand", hz=HZ, t0=10.0) as stream:
                assert stream.shape == (12, 16)
                stream.send(w.of("hand", day[:1])[0])  # (8, 12, 16): one window
                assert stream.wait(60) and len(stream.ids) == 1 and not stream.errors
            assert client.session("cl").counts == {"skin": 2, "hand": 1}

            example = w.of("hand", [day[3]])[0]
            r = c.post("/search/like", json={"sense": "hand", "frames": example.tolist(), "k": 3})
            top = r.json()["hits"][0]
            assert r.status_code == 200 and top["sense"] == "hand"
            assert top["t"] == float(day[3]) and top["cosine"] == pytest.approx(1, abs=1e-3)
            r = c.post("/search/like", json={"sense": "skin", "frames": example.tolist()})
            _problem(r, 422, "(8, 12, 16)", "(K, 16, 16)")

            # a taught label: the kettle is no STAG object; taught on the lesson's grasp it
            # answers with the lesson's windows
            for name in ("skin", "hand"):
                params = {"q": KETTLE, "k": 5, "sense": name, "group": "window"}
                r = c.post("/sessions/lesson/labels", json={"label": "kettle", "sense": name})
                assert r.status_code == 201 and r.json()["windows"] == len(lesson), r.text
                hits = c.get("/search", params=params).json()["hits"]
                taught = sum(h["session"] == "lesson" for h in hits)
                share = len(lesson) / (len(lesson) + len(day))  # a random window's chance
                print(f"{name}: {taught}/5 kettle hits from the taught session ({share:.2f})")
                assert len(hits) == 5 and taught >= 4 and taught / 5 > 2 * share, hits
            senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
            assert senses["skin"]["taught"] == ["kettle"] == senses["hand"]["taught"]

            # heat maps: each frame the sensor's H x W, the hand's gaps are no taxels
            frame_px = {"skin": (16 * SCALE, 16 * SCALE), "hand": (16 * SCALE, 12 * SCALE)}
            for name, item in (("skin", skin_ids[0]), ("hand", hand_ids[0])):
                r = c.get(f"/items/{item}/touch.png")
                fw, fh = frame_px[name]
                assert png_size(r.content) == (8 * fw + 7 * SCALE, fh + 4 + LEGEND_PX, "RGBA")
                lay = c.get(f"/items/{item}/touch.json").json()
                shape = list(PROFILES[name].shape)
                assert [lay["layout"]["frame_rows"], lay["layout"]["frame_cols"]] == shape
                assert np.array(lay["values"]).shape == (8, *shape)
            r = c.post("/render/touch.png", params={"legend": False},
                       json={"frames": example.tolist(), "sense": "hand"})  # fmt: skip
            assert png_size(r.content) == (8 * 64 + 7 * SCALE, 48, "RGBA")
            r = c.post("/render/touch.png", json={"frames": example.tolist(), "sense": "skin"})
            _problem(r, 422, "(8, 12, 16)", "(K, 16, 16)")
    finally:
        server.stop()
