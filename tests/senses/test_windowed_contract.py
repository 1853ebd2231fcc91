"""The windowed-sense contract (``senses/windowed.py``): what it promises (window parsing,
stream cutting) holds (the touch sense's own: tests/touch/test_encoder.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.senses.windowed import FrameStream
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


def test_the_default_cutter_cuts_frames_of_any_shape() -> None:
    """``FrameStream`` (what a windowed sense cuts with unless it brings its own): (6,) IMU
    frames pushed in pieces give the windows the whole run gives; stride > window skips."""
    frames = np.arange(11 * 6, dtype=np.float32).reshape(11, 6)  # (N, 6)
    times = np.arange(11, dtype=np.float64) / 10
    cut = FrameStream(3, 4)
    got = [cut.push(frames[i : i + 2], times[i : i + 2]) for i in range(0, 11, 2)]
    starts = [int(w[0, 0]) // 6 for done in got for w in done.frames]
    assert starts == [0, 4, 8]  # windows of frames 0-2, 4-6, 8-10
    assert all(w.shape == (3, 6) for done in got for w in done.frames)
    t = [float(x) for done in got for x in done.t_end]
    assert t == pytest.approx([0.2, 0.6, 1.0])
    assert cut.pending == 0
    cut.push(frames[:2], times[:2])  # frame 11 is skipped (stride 4), frame 12 waits
    assert cut.pending == 1
    with pytest.raises(InvalidInputError, match="frame shape changed"):
        cut.push(np.zeros((1, 5), np.float32), [2.0])
