"""A sensor is a profile: a checkpoint whose profile is a 16x16 array (STAG windows pooled 2x2,
a 12-bit raw scale) is a touch sense beside the 32x32 glove in one memory; each takes its
shape and calibration from its checkpoint, and a window of the wrong shape is an error that
names both shapes. Real MiniLM, real LanceDB, real STAG windows."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.touch.checkpoint import save_checkpoint
from tactus_memory.touch.model import create_model
from tactus_memory.touch.targets import build_targets
from tactus_memory.touch.windows import window_idle
from tactus_memory.training import stream_eval
from tactus_memory.training.data import load_stag
from tests.helpers.sensors import SKIN


def pooled(frames: np.ndarray) -> np.ndarray:
    """(..., 32, 32) glove raw -> (..., 16, 16) 12-bit raw: 2x2 mean, times 4."""
    f = np.asarray(frames, np.float32)
    p = f.reshape(*f.shape[:-2], 16, 2, 16, 2).mean(axis=(-3, -1)) * 4.0
    return np.clip(np.rint(p), 0, 4095).astype(np.int16)


@pytest.fixture(scope="module")
def skin_ckpt(tmp_path_factory, minilm_space):
    path = tmp_path_factory.mktemp("ck") / "skin16.safetensors"
    targets = build_targets(minilm_space, ["mug", "pen", "ball"])
    model = create_model("tactus-tiny", out_dim=minilm_space.dim)
    save_checkpoint(
        path, model, targets, space_dim=minilm_space.dim, calibration=SKIN.to_dict(), steps=0
    )
    return path


@pytest.fixture(scope="module")
def windows(stag_subset):
    data = load_stag(stag_subset("blindfolded_lite_train"))
    s = stream_eval.build_stream(data, [int(r) for r in np.unique(data.recording_id)[:8]])
    # windows in contact on both sensors (2x2 pooling softens a light touch below the bar),
    # strongest first
    on = [i for i in np.flatnonzero(~s.idle) if not window_idle(SKIN.scale(pooled(s.frames[i])))]
    keep = np.array(sorted(on, key=lambda i: -int(s.frames[i].max())))
    assert len(keep) >= 2
    return s.frames[keep], s.t[keep], s.t_end[keep]


def test_the_checkpoint_profile_gives_the_sense_its_shape(skin_ckpt, windows, minilm_space):
    enc = TactusEncoder(skin_ckpt, name="skin")
    assert enc.profile == SKIN and enc.profile.shape == (16, 16)
    raw = pooled(windows[0][0])
    got = enc.validate(raw)
    assert got.shape == (8, 16, 16)
    np.testing.assert_allclose(got, np.clip((raw - 2000.0) / 600.0, 0, 1), atol=1e-6)
    z = enc.embed([got])
    assert z.shape == (1, minilm_space.dim) and np.isclose(np.linalg.norm(z), 1.0, atol=1e-5)
    with pytest.raises(InvalidInputError, match=r"\(K, 16, 16\), got \(8, 32, 32\).*16x16"):
        enc.validate(windows[0][0])


def test_two_touch_senses_of_two_shapes_in_one_memory(tmp_path, skin_ckpt, windows, minilm_space):
    frames, t, t_end = windows
    with Memory.open(str(tmp_path / "m"), space=minilm_space, background=False) as mem:
        mem.add_sense(TactusEncoder())  # the 32x32 glove
        mem.add_sense(TactusEncoder(skin_ckpt, name="skin"))
        glove_ids = mem.add_many("s", "touch", list(frames), t=t.tolist(), t_end=t_end.tolist())
        skin_ids = mem.add_many(
            "s", "skin", list(pooled(frames)), t=t.tolist(), t_end=t_end.tolist()
        )
        assert len(glove_ids) == len(skin_ids) == len(frames)
        assert mem.get_item(skin_ids[0]).raw.shape == (8, 16, 16)
        with pytest.raises(InvalidInputError, match=r"\(K, 16, 16\), got \(8, 32, 32\)"):
            mem.add("s", "skin", frames[0], t=0.0)
        with pytest.raises(InvalidInputError, match=r"\(K, 32, 32\), got \(8, 16, 16\)"):
            mem.add("s", "touch", pooled(frames[0]), t=0.0)
        hits = mem.search("a hand holding a mug", k=50, senses=["touch", "skin"])
        assert {h.sense for h in hits} == {"touch", "skin"}
        # every stored window: an untrained model may tie more than a few at cosine 1
        like = mem.search_like("skin", pooled(frames[0]), k=len(frames))
        # the same window is stored: a cosine-1 example (an untrained model may tie others)
        assert {h.sense for h in like} == {"skin"} and like[0].cosine == pytest.approx(1, abs=1e-3)
        assert skin_ids[0] in {h.id for h in like if h.cosine > 1 - 1e-3}
        mem.teach("kettle", session="s", sense="skin")
        taught = {s.name: s.taught for s in mem.sense_info()}
        assert taught == {"text": [], "touch": [], "skin": ["kettle"]}
        info = {s.name: s for s in mem.sense_info()}
        assert info["skin"].classes == ["mug", "pen", "ball"]
        assert info["skin"].provenance["calibration"]["shape"] == [16, 16]
