"""Two sensors other than the 32x32 glove, made from the real STAG recordings for the tests of
issue 35 (no slice of STAG is ever stored: the frames are derived in the test, at run time):

* ``SKIN``: a 16x16 skin on a 12-bit raw scale (``tests/touch/test_sensor_shape.py``'s profile),
  here the glove max-pooled 2x2 (:func:`skin`: each skin taxel reads the firmest of its four
  glove taxels, so a light grasp stays in contact; the mean pooling of
  ``test_sensor_shape.pooled`` softens most of the blindfolded grasps below the contact bar);
* ``HAND``: a five-pad robot hand assembled into one 12x16 frame: four 4x4 fingertip pads side
  by side in rows 0-3 (thumb, index, middle, ring) and an 8x8 palm in rows 4-11, columns 4-11;
  the pixels between the pads are no taxels (:data:`HAND_MASK`) and read the offset (0
  calibrated). The pads take the skin's finger band (rows 0-3) and palm (rows 8-15,
  columns 4-11).

``train_checkpoint`` trains a ``tactus-tiny`` checkpoint for such a sensor with the library's
training loop (``touch.training.train.fit``: the recipe's cluster tuples and CE to the centred
class targets) on a STAG file converted to that sensor, in CI-sized time (150 steps, ~20 s on
one core); the checkpoint records the sensor's profile, so it serves any shape.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from tactus_memory.spaces.base import Space
from tactus_memory.touch.profile import SensorProfile
from tactus_memory.touch.targets import build_targets
from tactus_memory.touch.windows import window_idle
from tactus_memory.training import stream_eval
from tactus_memory.training.data import StagData, load_stag
from tactus_memory.training.train import TrainConfig, TrainData, fit

#: the hand's raw scale: 12-bit like the skin (its frames come from the pooled glove)
HAND = SensorProfile("hand5", offset=2000.0, span=600.0, shape=(12, 16), saturation_raw=4095.0)
#: (name, rows, cols) of each pad in the hand's 12x16 frame
HAND_PADS = (
    ("thumb", slice(0, 4), slice(0, 4)),
    ("index", slice(0, 4), slice(4, 8)),
    ("middle", slice(0, 4), slice(8, 12)),
    ("ring", slice(0, 4), slice(12, 16)),
    ("palm", slice(4, 12), slice(4, 12)),
)
HAND_MASK = np.zeros(HAND.shape, bool)
for _name, _rows, _cols in HAND_PADS:
    HAND_MASK[_rows, _cols] = True

__all__ = [
    "HAND",
    "HAND_MASK",
    "HAND_PADS",
    "SKIN",
    "hand",
    "session_checkpoint",
    "skin",
    "train_checkpoint",
]


def skin(frames: np.ndarray) -> np.ndarray:
    """(..., 32, 32) glove raw -> (..., 16, 16) 12-bit raw: 2x2 max, times 4."""
    f = np.asarray(frames, np.float32)
    p = f.reshape(*f.shape[:-2], 16, 2, 16, 2).max(axis=(-3, -1)) * 4.0
    return np.clip(np.rint(p), 0, 4095).astype(np.int16)


def hand(frames: np.ndarray) -> np.ndarray:
    """(..., 32, 32) glove raw -> (..., 12, 16) five-pad hand raw (12-bit)."""
    p = skin(frames)  # (..., 16, 16)
    out = np.full((*p.shape[:-2], *HAND.shape), int(HAND.offset), np.int16)
    out[..., 0:4, :] = p[..., 0:4, :]  # the four fingertip pads
    out[..., 4:12, 4:12] = p[..., 8:16, 4:12]  # the palm
    return out


#: training steps of a test checkpoint (train accuracy ~0.85 on the skin, ~0.6 on the hand)
TRAIN_STEPS = 150


def train_checkpoint(
    path: Path,
    profile: SensorProfile,
    convert: Callable[[np.ndarray], np.ndarray],
    data: StagData,
    space: Space,
    steps: int = TRAIN_STEPS,
) -> Path:
    """A tactus-tiny checkpoint for ``profile`` trained on ``data`` converted by ``convert``
    ((N, 32, 32) glove raw -> (N, H, W) raw of the sensor), every recording in training."""
    calibrated = profile.scale(convert(data.pressure))  # (N, H, W) float32
    train = TrainData(
        calibrated=calibrated,
        labels=np.asarray(data.object_id, np.int64),
        recording_id=np.asarray(data.recording_id, np.int64),
        train_valid=np.asarray(data.valid, bool).copy(),
        heldout_valid=np.zeros(len(calibrated), bool),
        classes=list(data.objects),
        calibration=profile.to_dict(),
    )
    cfg = TrainConfig(model="tactus-tiny", steps=steps, batch=32, warmup=10, save_every=10**9)
    targets = build_targets(space, list(data.objects))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a shared CPU: spinning OpenMP threads slow a small model 3x
    try:
        fit(train, targets, cfg, path, space_dim=space.dim, device="cpu", progress=False)
    finally:
        torch.set_num_threads(threads)
    return path


def session_checkpoint(
    tmp_path_factory: pytest.TempPathFactory, name: str, data: StagData, space: Space
) -> Path:
    """``train_checkpoint`` for sensor ``name`` (``PROFILES``/``CONVERT``), trained once per test
    session: the test files that serve the same sensor (``tests/service/test_sensor_serving.py``,
    ``test_sensor_browser.py``) share it. Under pytest-xdist the workers share the parent of
    their base temp folders, so the first worker to ask trains it under a file lock and the
    others wait for it and read it; a plain run keeps it in its own base temp folder. Keyed by
    the sensor, the steps, the space and the data's fingerprint: another input trains anew."""
    from filelock import FileLock  # a dependency of torch: the test extra installs it

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    key = f"{name}-{TRAIN_STEPS}-{space.name}-{space.dim}-{data.fingerprint()[:16]}"
    folder = shared / "session-checkpoints" / key
    folder.mkdir(parents=True, exist_ok=True)
    path, done = folder / f"{name}.safetensors", folder / "done"
    with FileLock(str(folder.with_suffix(".lock"))):
        if not done.is_file():  # a run killed while training leaves no "done": train anew
            train_checkpoint(path, PROFILES[name], CONVERT[name], data, space)
            done.touch()
    return path


#: 12-bit raw scale: the glove's 0..1023-ish counts times 4, offset and span scaled alike
SKIN = SensorProfile("skin16", offset=2000.0, span=600.0, shape=(16, 16), saturation_raw=4095.0)


@pytest.fixture(scope="module")
def stag(stag_subset):
    return load_stag(stag_subset("blindfolded_lite_train"))


@pytest.fixture(scope="module")
def windows(stag) -> Windows:
    recs = [int(r) for r in np.unique(stag.recording_id)[:RECORDINGS]]
    s = stream_eval.build_stream(stag, recs)
    on = [
        i
        for i in np.flatnonzero(~s.idle)
        if all(not window_idle(PROFILES[n].scale(CONVERT[n](s.frames[i]))) for n in CONVERT)
    ]
    assert len(on) >= 20, len(on)
    taught = Counter(s.recording[i] for i in on).most_common(1)[0][0]
    lesson = np.array([s.recording[i] == taught for i in on])
    return Windows(s.frames[on], [s.obj[i] for i in on], lesson)


CONVERT = {"skin": skin, "hand": hand}


PROFILES = {"skin": SKIN, "hand": HAND}


RECORDINGS = 16  # the blindfolded file's first recordings streamed (one object each)


@dataclass
class Windows:
    """Stream windows in contact on both derived sensors: ``frames`` (N, 8, 32, 32) glove raw,
    ``obj`` (N,) object names, ``lesson`` (N,) bool: the windows of the recording with the
    most of them (the taught grasp)."""

    frames: np.ndarray
    obj: list[str]
    lesson: np.ndarray

    def of(self, sense: str, idx: np.ndarray | list[int] | None = None) -> np.ndarray:
        """(n, 8, H, W) raw windows of ``sense``'s sensor."""
        frames = self.frames if idx is None else self.frames[np.asarray(idx)]
        return CONVERT[sense](frames)
