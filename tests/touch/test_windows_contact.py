"""Contact-aware stream windowing: per-window contact, idle flag, frame selection (span)."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.windows import (
    CONTACT_MIN_TAXELS,
    WindowStream,
    contact_taxels,
    cut_windows,
)
from tactus_memory.training.data import combine, load_stag

REST = 512  # raw resting reading of the STAG glove


def _stream(n: int, touch: set[int], taxels: int = 12) -> np.ndarray:
    """(n, 32, 32) raw int16: rest everywhere, ``taxels`` pressed to raw 600 in frames ``touch``."""
    frames = np.full((n, 32, 32), REST, np.int16)
    for i in touch:
        frames[i].reshape(-1)[:taxels] = 600
    return frames


def test_contact_counts_raw_and_calibrated_agree() -> None:
    raw = _stream(4, {1, 3}, taxels=7)
    cal = np.clip((raw.astype(np.float32) - 500) / 150, 0, 1)
    assert contact_taxels(raw).tolist() == [0, 7, 0, 7]
    assert contact_taxels(cal).tolist() == [0, 7, 0, 7]


def test_idle_windows_are_flagged_and_touch_windows_are_not() -> None:
    frames = _stream(32, set(range(16, 32)))  # 16 idle frames, then a grasp
    out = cut_windows(frames, np.arange(32) / 30, window=8, stride=8)
    assert out.idle.tolist() == [True, True, False, False]
    assert out.contact.tolist() == [0, 0, 12, 12]
    kept = out.take(~out.idle)
    assert kept.start.tolist() == [16, 24] and kept.frames.shape == (2, 8, 32, 32)


def test_one_touched_taxel_is_still_idle() -> None:
    out = cut_windows(
        _stream(8, {3}, taxels=CONTACT_MIN_TAXELS - 1), np.arange(8), window=8, stride=8
    )
    assert out.idle.tolist() == [True]


def test_span_keeps_the_most_contact_frames_in_time_order() -> None:
    frames = _stream(16, {2, 5, 7, 9, 11, 12, 13, 15})
    frames[[2, 5, 7, 9, 11, 12, 13, 15]] += np.arange(8, dtype=np.int16)[:, None, None]
    out = cut_windows(frames, np.arange(16) / 30, window=8, stride=16, span=16)
    assert len(out) == 1
    picked = [int(f.reshape(-1)[0]) for f in out.frames[0]]
    assert picked == [600 + i for i in range(8)]  # exactly the 8 touched frames, in order
    assert out.t[0] == 0 and out.t_end[0] == pytest.approx(15 / 30)  # span covers all 16


def test_span_ties_keep_the_earliest_frames() -> None:
    frames = _stream(12, set())
    frames[:, 0, 0] = np.arange(12)  # tag frames (below contact level)
    out = cut_windows(frames, np.arange(12), window=8, stride=12, span=12)
    assert out.frames[0, :, 0, 0].tolist() == list(range(8))


@pytest.mark.parametrize(("k", "s", "span", "chunk"), [(8, 4, 12, 5), (8, 8, 16, 3), (4, 2, 4, 7)])
def test_window_stream_with_span_equals_whole_cut(k: int, s: int, span: int, chunk: int) -> None:
    rng = np.random.default_rng(0)
    frames = (REST + rng.integers(0, 40, size=(61, 32, 32))).astype(np.int16)
    times = np.arange(61) / 30
    whole = cut_windows(frames, times, window=k, stride=s, span=span)
    ws = WindowStream(k, s, span=span)
    parts = [ws.push(frames[i : i + chunk], times[i : i + chunk]) for i in range(0, 61, chunk)]
    assert np.array_equal(np.concatenate([p.frames for p in parts]), whole.frames)
    assert np.concatenate([p.start for p in parts]).tolist() == whole.start.tolist()
    assert np.concatenate([p.contact for p in parts]).tolist() == whole.contact.tolist()


def test_span_shorter_than_window_is_refused() -> None:
    with pytest.raises(InvalidInputError, match="span"):
        cut_windows(_stream(16, set()), np.arange(16), window=8, stride=8, span=4)


def test_real_stag_labelled_grasps_are_not_idle(stag_dir) -> None:
    """Real glove: windows holding a labelled grasp frame are (almost) never idle; the
    blindfolded recordings' approach phase before the grasp is mostly idle."""
    d = combine(
        [load_stag(stag_dir / "weights_lite"), load_stag(stag_dir / "blindfolded_lite_train")]
    )
    idle, labelled, first_idle = [], [], []
    for r in np.unique(d.recording_id):
        m = np.flatnonzero(d.recording_id == r)
        out = cut_windows(d.pressure[m], d.ts[m], window=8, stride=4)
        idle.append(out.idle)
        labelled += [bool(d.valid[m][s : s + 8].any()) for s in out.start]
        if d.subset[m[0]] == 1 and len(out):
            first_idle.append(bool(out.idle[0]))
    idle_all, lab = np.concatenate(idle), np.asarray(labelled)
    assert lab.sum() > 800
    assert (idle_all & lab).sum() / lab.sum() < 0.03  # measured 11 / 893
    assert 0.1 < idle_all.mean() < 0.6  # real streams do contain idle stretches
    assert np.mean(first_idle) > 0.7  # a blindfolded recording starts before the touch
