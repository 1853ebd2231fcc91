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
