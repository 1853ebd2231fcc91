"""The contact level of the idle rule is the sensor's (issue 46, item 5): a profile may set
it, the windowing and the touch sense read it through ``touch.windows.contact_level``."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile
from tactus_memory.touch.windows import (
    CONTACT_LEVEL,
    contact_level,
    contact_taxels,
    cut_windows,
    window_idle,
)

SOFT = SensorProfile(name="soft", offset=0.0, span=100.0, shape=(16, 16), contact_level=0.05)


def test_the_level_is_the_profiles_or_the_gloves() -> None:
    assert contact_level(None) == contact_level(STAG_GLOVE) == CONTACT_LEVEL
    assert contact_level(SOFT) == 0.05
    assert SensorProfile.from_dict(SOFT.to_dict()) == SOFT
    assert "contact_level" not in STAG_GLOVE.to_dict()  # old profile dicts stay equal
    with pytest.raises(InvalidInputError, match="contact_level"):
        SensorProfile(name="bad", offset=0.0, span=1.0, contact_level=1.5)


def test_a_soft_sensors_grasp_is_kept_at_its_own_level() -> None:
    raw = np.zeros((8, 16, 16), np.float32)
    raw[:, 4:8, 4:8] = 10.0  # 0.10 calibrated: under the glove's 1/6, over the soft level
    assert (contact_taxels(raw, SOFT) == 16).all()
    cal = SOFT.calibrate(raw)
    assert window_idle(cal) and not window_idle(cal, contact_level(SOFT))
    w = cut_windows(raw, np.arange(8) / 30.0, window=8, stride=4, profile=SOFT)
    assert not w.idle.any()
    assert cut_windows(raw, np.arange(8) / 30.0, window=8, stride=4, profile=STAG_GLOVE).idle.all()


def test_a_sensor_file_sets_the_level() -> None:
    from tactus_memory.touch.sensor_file import profile_from_toml_dict

    d = {"name": "soft", "shape": [16, 16], "span": 100.0, "contact_level": 0.05}
    assert contact_level(profile_from_toml_dict(d)) == 0.05
    with pytest.raises(InvalidInputError, match="contact_level"):
        profile_from_toml_dict(d | {"contact_level": 0.0})


def test_the_level_is_estimated_from_a_sensors_labelled_frames() -> None:
    from tactus_memory.touch.windows import CONTACT_QUANTILE, estimate_contact_level

    rng = np.random.default_rng(0)
    frames = np.zeros((100, 16, 16), np.float32)
    second = np.linspace(0.05, 0.5, 100)  # each frame's 2nd highest taxel
    frames[:, 0, 0], frames[:, 0, 1] = 0.9, second
    frames[:, 5:, 5:] = rng.uniform(0.0, 0.01, (100, 11, 11))  # rest noise, below them
    assert estimate_contact_level(frames) == pytest.approx(np.quantile(second, CONTACT_QUANTILE))
    with pytest.raises(InvalidInputError, match="labelled frames"):
        estimate_contact_level(np.zeros((0, 16, 16)))


def test_training_another_sensor_records_its_estimated_level(tmp_path) -> None:
    """``prepare_data`` (what ``tactus train`` records in the checkpoint's calibration) sets a
    non-glove sensor's level from its training recordings' labelled frames; the glove keeps
    its measured 1/6 (not estimated); a profile that sets one keeps it."""
    from tactus_memory.touch.windows import estimate_contact_level
    from tactus_memory.training.train import load_data, prepare_data

    rng = np.random.default_rng(1)
    n = 120
    pressure = rng.integers(0, 3, (n, 16, 16)).astype(np.int16)  # resting noise
    pressure[:, 6:9, 6:9] += rng.integers(5, 40, (n, 1, 1)).astype(np.int16)  # light grasps
    label = np.array(["cup", "pen"] * (n // 2))
    recording = np.array([f"r{i % 4}" for i in range(n)])
    np.savez(tmp_path / "soft.npz", pressure=pressure, label=label, recording=recording)
    plain = SensorProfile(name="soft", offset=0.0, span=100.0, shape=(16, 16))
    data = load_data([tmp_path / "soft.npz"], profile=plain)
    held = [data.recordings.index("r3/cup") if "r3/cup" in data.recordings else 0]
    td = prepare_data(data, held, profile=plain)
    train = data.valid & ~np.isin(data.recording_id, held)
    want = estimate_contact_level(plain.scale(data.pressure[train]))
    assert td.calibration["contact_level"] == pytest.approx(want) and want < CONTACT_LEVEL
    fixed = prepare_data(data, held, profile=SOFT).calibration["contact_level"]
    assert fixed == SOFT.contact_level
