"""Training on your own sensor, end to end through the CLI (issue 35, part A): `tactus train
--data FILE.npz` with the sensor from flags or a TOML file, `tactus train --bag` from a real ROS 2
bag with a label topic, and `tactus eval` on the .npz, with the real MiniLM targets. Two
sensors: STAG recordings pooled 2x2 into a 16x16 array with a 12-bit raw scale (made here from
the shared STAG files; skipped without them), and a synthetic five-pad hand whose pad layout
comes from a TOML profile. Each trains `tactus-tiny` for a few dozen steps and must rank the
held-out windows' classes above chance."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import httpx
import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.cli import app
from tactus_memory.recordings.samples import int16_array, note, write_bag
from tactus_memory.touch.checkpoint import load_checkpoint
from tactus_memory.touch.profile import SensorProfile
from tactus_memory.touch.sensor_file import load_profile_toml
from tactus_memory.touch.targets import natural_name, with_article
from tactus_memory.touch.windows import window_idle
from tactus_memory.training.data import load_stag
from tests.helpers.hand_synth import HAND_SHAPE, OBJECTS, as_arrays, recordings, write_toml
from tests.helpers.servers import Server
from tests.helpers.training import _last_json

pytestmark = pytest.mark.slow

#: CI-sized training: the smallest model, small batches, one thread (a loaded 2-core machine),
#: and BatchNorm statistics recomputed after the short run (without, eval mode collapses onto
#: one class on the 16x16 skin: touch/training/precise_bn.py)
TINY = ["--model", "tactus-tiny", "--threads", "1", "--batch", "8", "--seed", "0"]
TINY += ["--precise-bn", "20"]
STEPS = ["--steps", "60"]
HZ = 30.0  # the hand's frame rate in the bag
NS = 1_000_000_000


def _run(args: list[str]) -> str:
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, (r.output[-3000:], r.exception)
    return r.output


@pytest.fixture(scope="module")
def hand_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("hand")


@pytest.fixture(scope="module")
def hand(hand_dir) -> SensorProfile:
    return load_profile_toml(write_toml(hand_dir))


def test_a_five_pad_hand_trains_from_npz_and_evaluates(hand_dir, hand) -> None:
    npz = hand_dir / "hand.npz"
    np.savez(npz, **as_arrays(recordings(hand, per_object=4, frames=32, seed=0)))
    out, mae = hand_dir / "hand.safetensors", hand_dir / "mae.safetensors"
    src = ["--data", npz, "--sensor", hand_dir / "hand.toml", "--holdout", "one-per-object@"]
    # MAE on the hand's 12x16 frames (smoke-sized), then the recipe from it
    _run(["pretrain", *src, "--out", mae, "--steps", 3, "--batch", 8, *TINY[:4]])
    summary = _last_json(_run(["train", *src, "--out", out, "--pretrained", mae, *STEPS, *TINY]))
    assert summary["pretrained"] == str(mae)
    held = summary["heldout"]
    chance = 1 / len(OBJECTS)
    assert held["recordings"] == len(OBJECTS) and held["chance_top1"] == pytest.approx(chance)
    print("hand .npz held-out:", {k: held[k] for k in ("top1", "top3", "recording_top1")})
    assert held["top1"] > 2 * chance, held  # 5 objects, one unseen grasp of each
    ck = load_checkpoint(out)
    recorded = SensorProfile.from_dict(ck.meta["calibration"])
    # the hand's file sets no contact level: training estimated one from its labelled frames
    assert recorded.contact_level is not None and 0 < recorded.contact_level < 1
    assert dataclasses.replace(recorded, contact_level=None) == hand  # pads and all
    assert ck.model.cfg.frame_shape == HAND_SHAPE and sorted(ck.classes) == sorted(OBJECTS)
    # the served sense reads the hand's frames
    enc = TactusEncoder(out, name="hand")
    assert enc.profile.shape == HAND_SHAPE and [p.name for p in enc.profile.pads][0] == "thumb"
    # `tactus eval` on the same .npz, the profile from the checkpoint
    ev = ["--data", npz, "--holdout", "one-per-object@", "--no-analysis"]
    report = _last_json(_run(["eval", "--checkpoint", out, *ev, "--json", hand_dir / "e.json"]))
    assert report["n_recordings"] == len(OBJECTS)
    print("hand eval:", {k: report[k] for k in ("top1", "top3", "top1_vote", "recording_top1")})
    assert report["top1"] > 2 * chance and report["recording_top1"] > chance, report


def _bag_messages(hand: SensorProfile) -> list:
    """Three grasps of every object on /hand/tactile (Int16MultiArray, 30 Hz) with /labels:
    most as a running label then "none", every fourth as an explicit span "obj T0 T1"; the
    hand at rest between grasps."""
    msgs, t = [], 0
    for i, (obj, frames) in enumerate(recordings(hand, per_object=3, frames=32, seed=1)):
        if i % 4 == 3:
            t0, t1 = (t - 0.5) / HZ, (t + len(frames) - 0.5) / HZ  # half a frame of margin
            msgs.append(note("/labels", int(t * NS / HZ), f"{obj} {t0:.4f} {t1:.4f}"))
        else:
            msgs.append(note("/labels", int(t * NS / HZ), obj))
        rest = [np.full(HAND_SHAPE, hand.rest_raw, np.int16)] * 4
        for f in [*frames, *rest]:
            msgs.append(int16_array("/hand/tactile", int(t * NS / HZ) + 1, f))
            t += 1
        msgs.append(note("/labels", int((t - len(rest)) * NS / HZ), "none"))
    return msgs


@pytest.fixture(scope="module")
def bag_trained(hand_dir, hand) -> tuple[Path, dict]:
    """``tactus train --bag`` on a real ROS 2 bag with a label topic: (checkpoint, summary)."""
    bag = write_bag(hand_dir / "hand_bag", _bag_messages(hand))
    out = hand_dir / "bag.safetensors"
    src = ["--bag", bag, "--topic", "/hand/tactile", "--labels", "/labels"]
    src += ["--sensor", hand_dir / "hand.toml", "--holdout", "one-per-object@"]
    return out, _last_json(_run(["train", *src, "--out", out, *STEPS, *TINY]))


def test_a_five_pad_hand_trains_from_a_bag_with_a_label_topic(bag_trained) -> None:
    _, summary = bag_trained
    held = summary["heldout"]
    chance = 1 / len(OBJECTS)
    assert held["recordings"] == len(OBJECTS), held  # each grasp is one recording
    assert all(name.startswith("hand_bag#") for name in held["recordings_named"])
    print("hand bag held-out:", {k: held[k] for k in ("top1", "top3", "recording_top1")})
    assert held["top1"] > 2 * chance, held


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_the_hand_trained_from_its_bag_is_served_and_answers(bag_trained, hand, tmp_path) -> None:
    """From the bag to answers over real HTTP: ``tactus serve --touch hand=CKPT`` beside the
    glove; fresh grasps of every object posted to ``?sense=hand`` as ``.npy`` windows; text
    questions find the right grasp above chance; a glove-shaped window is a 422 naming the
    hand's shape; a taught label is listed with the hand's classes."""
    ckpt, _ = bag_trained
    server = Server(tmp_path / "mem", tmp_path / "serve.log", "--touch", f"hand={ckpt}")
    try:
        with httpx.Client(base_url=server.base, timeout=120) as c:
            senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
            assert senses["hand"]["shape"] == list(HAND_SHAPE)
            for obj, frames in recordings(hand, per_object=1, frames=16, seed=7):  # unseen
                wins = frames.reshape(2, 8, *HAND_SHAPE)  # (B, K, 12, 16) raw
                r = c.post(
                    f"/sessions/s-{obj}/touch",
                    params={"sense": "hand", "t": [0.0, 0.3]},
                    content=_npy(wins),
                    headers={"Content-Type": "application/x-npy"},
                )
                assert r.status_code == 201, r.text
            right = 0
            for obj in OBJECTS:
                q = {"q": f"holding a {obj}", "sense": "hand", "k": 1}
                hits = c.get("/search", params=q).json()["hits"]
                right += bool(hits) and hits[0]["session"] == f"s-{obj}"
            print(f"hand served: {right}/{len(OBJECTS)} questions answered by the right grasp")
            assert right >= 2  # chance: 1 of 5
            glove = {"frames": np.zeros((8, 32, 32)).tolist(), "t": 1.0}
            r = c.post("/sessions/x/touch", params={"sense": "hand"}, json=glove)
            assert r.status_code == 422 and "12x16" in r.text and "32" in r.text, r.text
            body = {"label": "stapler", "t": 0.0, "t_end": 1.0, "sense": "hand"}
            assert c.post("/sessions/s-pen/labels", json=body).status_code == 201
            assert "stapler" in str(c.get("/senses").json())
    finally:
        server.stop()


def pooled(frames: np.ndarray) -> np.ndarray:
    """(..., 32, 32) glove raw -> (..., 16, 16) 12-bit raw: 2x2 mean, times 4."""
    f = np.asarray(frames, np.float32)
    p = f.reshape(*f.shape[:-2], 16, 2, 16, 2).mean(axis=(-3, -1)) * 4.0
    return np.clip(np.rint(p), 0, 4095).astype(np.int16)


#: the derived sensor: a 16x16 array whose raw counts are the glove's x4 (offset and span too)
SKIN_FLAGS = ["--shape", "16x16", "--offset", "2000", "--span", "600"]
N_CLASSES = 10  # the objects with the most labelled frames in weights_lite
HELD_FRACTION = 0.3  # each recording's last 30% of labelled frames are held out ...
GAP_FRACTION = 0.1  # ... after a 10% gap that is not trained on
WINDOW = 8  # frames of a served window (the model's K)
TOP = 5  # windows a text query returns


def test_stag_pooled_into_a_16x16_skin_trains_from_npz(stag_subset, tmp_path, minilm_space):
    d = load_stag(stag_subset("weights_lite"))
    counts = np.bincount(d.object_id[d.valid], minlength=len(d.objects))
    d = d.select(np.isin(d.object_id, np.argsort(-counts, kind="stable")[:N_CLASSES]))
    rec = np.array([d.recordings[r] for r in d.recording_id], dtype=object)
    valid = d.valid.copy()
    held = []
    for r in np.unique(d.recording_id):
        v = np.flatnonzero((d.recording_id == r) & d.valid)
        cut = int(len(v) * (1 - HELD_FRACTION))
        gap = int(len(v) * (1 - HELD_FRACTION - GAP_FRACTION))
        rec[v[cut:]] += ":late"
        valid[v[gap:cut]] = False
        held.append(f"{d.recordings[r]}:late")
    npz = tmp_path / "skin16.npz"
    skin = pooled(d.pressure)  # (N, 16, 16) int16 raw
    np.savez(
        npz, pressure=skin, label=np.array(d.objects)[d.object_id],
        recording=rec.astype(str), valid=valid, t=d.ts,
    )  # fmt: skip
    out = tmp_path / "skin.safetensors"
    src = ["--data", npz, *SKIN_FLAGS, "--holdout", "recordings@" + ",".join(held)]
    summary = _last_json(_run(["train", *src, "--out", out, *STEPS, *TINY]))
    held_m = summary["heldout"]
    assert held_m["recordings"] == N_CLASSES and held_m["chance_top1"] == 1 / N_CLASSES
    ck = load_checkpoint(out)
    assert ck.meta["calibration"]["shape"] == [16, 16] and ck.model.cfg.frame_shape == (16, 16)
    chance = 1 / N_CLASSES
    print("skin16 held-out:", {k: held_m[k] for k in ("top1", "top3", "recording_top1")})
    assert held_m["top1"] > 2 * chance and held_m["top3"] > 3 * chance, held_m
    # text queries through the served sense: "a hand holding a mug" (MiniLM, the query
    # transform) ranks the held-out windows (8 consecutive labelled frames, raw 16x16)
    enc = TactusEncoder(out, name="skin")
    wins, truth = [], []
    for r in np.unique(d.recording_id):
        v = np.flatnonzero((d.recording_id == r) & d.valid)
        late = v[int(len(v) * (1 - HELD_FRACTION)) :]
        for s in range(0, len(late) - WINDOW + 1, WINDOW):
            w = enc.validate(skin[late[s : s + WINDOW]], keep_idle=True)
            if not window_idle(w):  # the memory never stores an idle window as a grasp
                wins.append(w)
                truth.append(int(d.object_id[late[0]]))
    z = enc.embed(wins)  # (W, D) unit rows
    names = [d.objects[c] for c in range(len(d.objects))]
    classes = sorted(set(truth))
    texts = [f"a hand holding {with_article(natural_name(names[c]))}" for c in classes]
    q = ck.targets.query_transform(minilm_space.embed_texts(texts, query=True))  # (C, D)
    top = np.argsort(-(q @ z.T), axis=1)[:, :TOP]  # (C, TOP) window indices, best first
    precision = np.mean([np.mean(np.array(truth)[top[i]] == c) for i, c in enumerate(classes)])
    print(f"skin16 text queries: precision@{TOP} {precision:.3f} (chance {chance:.3f})")
    assert precision > 2 * chance
