"""The windowed-sense contract (``senses/windowed.py``): what it promises (window parsing,
stream cutting) holds (the touch sense's own: tests/touch/test_encoder.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tests.helpers.service import StandInTouch


def test_parse_window_names_the_shape_it_needs() -> None:
    sense = StandInTouch(8)
    arr = sense.parse_window(np.ones((3, 32, 32)).tolist())
    assert arr.shape == (3, 32, 32) and arr.dtype == np.float32
    for bad, says in (
        (np.ones((3, 16, 32)), "(K, 32, 32)"),
        (np.ones((32, 32)), "got shape (32, 32)"),
        (np.zeros((0, 32, 32)), "got shape (0, 32, 32)"),
        ([["a"]], "numbers"),
        (np.full((2, 32, 32), np.nan), "NaN"),
    ):
        with pytest.raises(InvalidInputError, match=says.replace("(", r"\(").replace(")", r"\)")):
            sense.parse_window(bad)


def test_the_stream_cutter_cuts_frames_into_windows() -> None:
    sense = StandInTouch(8)
    cut = sense.window_stream(4, 2)
    frames = np.random.default_rng(0).random((9, 32, 32)).astype(np.float32)
    done = cut.push(frames, [float(i) for i in range(9)])
    assert len(done) == 3  # windows at frames 0-3, 2-5, 4-7
    assert done.frames[0].shape == (4, *sense.frame_shape)
    assert np.array_equal(done.frames[1], frames[2:6])
    assert cut.pending > 0
