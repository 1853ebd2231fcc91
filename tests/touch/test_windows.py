"""Stream windowing (tactus_memory.touch.windows): one cut for the live stream and ingest."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.windows import WindowStream, cut_windows


def _run(n: int) -> tuple[np.ndarray, np.ndarray]:
    frames = np.arange(n, dtype=np.float32)[:, None, None] * np.ones((1, 32, 32), np.float32)
    return frames, np.arange(n) / 30.0


@pytest.mark.parametrize(("k", "s"), [(8, 8), (8, 4), (8, 11), (1, 1), (5, 3)])
def test_cut_windows_shapes_and_spans(k: int, s: int) -> None:
    frames, times = _run(50)
    out = cut_windows(frames, times, window=k, stride=s)
    assert len(out) == (50 - k) // s + 1
    assert out.frames.shape == (len(out), k, 32, 32)
    for j in range(len(out)):
        first = j * s
        assert out.start[j] == first
        assert out.frames[j, :, 0, 0].tolist() == list(range(first, first + k))
        assert out.t[j] == pytest.approx(times[first])
        assert out.t_end[j] == pytest.approx(times[first + k - 1])


def test_short_run_has_no_window() -> None:
    frames, times = _run(7)
    out = cut_windows(frames, times, window=8, stride=8)
    assert len(out) == 0 and out.frames.shape == (0, 8, 32, 32)


@pytest.mark.parametrize(("k", "s"), [(8, 8), (8, 3), (8, 13), (3, 1)])
@pytest.mark.parametrize("chunk", [1, 2, 7, 64])
def test_stream_matches_whole_run(k: int, s: int, chunk: int) -> None:
    frames, times = _run(97)
    whole = cut_windows(frames, times, window=k, stride=s)
    ws = WindowStream(k, s)
    parts = [ws.push(frames[i : i + chunk], times[i : i + chunk]) for i in range(0, 97, chunk)]
    got = np.concatenate([p.frames for p in parts])
    assert np.array_equal(got, whole.frames)
    assert np.array_equal(np.concatenate([p.start for p in parts]), whole.start)
    assert np.allclose(np.concatenate([p.t_end for p in parts]), whole.t_end)
    assert ws.pending < k


def test_bad_arguments_are_named() -> None:
    frames, times = _run(10)
    with pytest.raises(InvalidInputError, match="stride"):
        cut_windows(frames, times, window=8, stride=0)
    with pytest.raises(InvalidInputError, match="9 times for 10 frames"):
        cut_windows(frames, times[:9], window=8, stride=8)
    ws = WindowStream(4, 4)
    ws.push(frames[:2], times[:2])
    with pytest.raises(InvalidInputError, match="frame shape changed"):
        ws.push(np.zeros((1, 16, 16)), [1.0])
