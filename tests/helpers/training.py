import json
from typing import Any

import numpy as np
from typer.testing import CliRunner

from tactus_memory.cli import app
from tactus_memory.touch.targets import Targets, centre
from tactus_memory.training.train import TrainData

N_CLS, DIM = 4, 16


def synthetic(rec_per_class: int = 3, frames_per_rec: int = 24, seed: int = 0) -> TrainData:
    """Class c presses a 6x6 blob at a class-specific place (jittered); rest ~0.07."""
    rng = np.random.default_rng(seed)
    centres = [(5, 5), (5, 24), (24, 5), (24, 24)]
    frames, labels, recs = [], [], []
    r = 0
    for c in range(N_CLS):
        for _ in range(rec_per_class):
            for _ in range(frames_per_rec):
                f = np.full((32, 32), 0.07, np.float32) + rng.normal(0, 0.01, (32, 32))
                y, x = centres[c][0] + rng.integers(-2, 3), centres[c][1] + rng.integers(-2, 3)
                f[y - 3 : y + 3, x - 3 : x + 3] += rng.uniform(0.3, 0.8)
                frames.append(np.clip(f, 0, 1).astype(np.float32))
                labels.append(c)
                recs.append(r)
            r += 1
    rec = np.array(recs)
    held = rec % rec_per_class == 0  # one recording per class held out
    return TrainData(
        calibrated=np.stack(frames),
        labels=np.array(labels),
        recording_id=rec,
        train_valid=~held,
        heldout_valid=held,
        classes=[f"c{i}" for i in range(N_CLS)],
    )


def orthogonal_targets() -> Targets:
    raw = np.eye(N_CLS, DIM, dtype=np.float32) * 0.8 + 0.6 * np.eye(1, DIM, DIM - 1)
    raw /= np.linalg.norm(raw, axis=1, keepdims=True)
    c = raw.mean(0)
    return Targets(
        [f"c{i}" for i in range(N_CLS)],
        [f"p{i}" for i in range(N_CLS)],
        raw,
        c,
        centre(raw, c),
        "toy",
    )


HOLDOUT = "one-per-object@blindfolded"


def _run(args: list[str]) -> str:
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, (r.output, r.exception)
    return r.output


def _last_json(output: str) -> dict[str, Any]:
    """The last top-level JSON object the command printed (``json.dumps(indent=2)``; progress
    bars on the same stream may precede it without a line break)."""
    dec = json.JSONDecoder()
    found: list[dict[str, Any]] = []
    end = 0
    pos = output.find("{\n")
    while pos != -1:
        if pos >= end:  # not inside the previous object
            try:
                obj, end = dec.raw_decode(output, pos)
                found.append(obj)
            except json.JSONDecodeError:
                pass
        pos = output.find("{\n", pos + 1)
    assert found, output[-2000:]
    return found[-1]
