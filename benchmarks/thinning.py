"""The cosine of stale-duplicate thinning, measured on real data (issue 25).

    python benchmarks/thinning.py [--out benchmarks/results/thinning.json]

Thinning (``tactus_memory.storage.retention``) drops old items whose vector is within a cosine
of a kept neighbour of the same session, sense and source. The bar must merge a hand holding
an object still (one grasp, window after window) and never merge a change.

Touch: the STAG ``weights_lite`` and ``blindfolded_lite_train`` recordings
(``$TACTUS_STAG_DIR``, 7.4 Hz), cut into the service's windows (``Settings().window``/
``stride``: what a glove stream stores), idle windows dropped as the touch sense does, and
embedded by the shipped Tactus checkpoint. Adjacent stored windows of one recording are
ranked by how much the pressure changed between them (mean absolute difference of their
mean calibrated frames): the lowest fifth is the hand **held still**, the highest fifth the
hand **moving** (closing, opening, regrasping). Pairs of windows of **different objects**
(the middle window of each recording, every pair of recordings of different objects, the
empty hand left out) show how close unrelated grasps come. The bar is the
smallest cosine that no more than 1% of moving pairs and 1% of different-object pairs
reach, rounded up to 0.005; the JSON gives the share of still pairs it thins (and of moving
and different-object pairs it would merge).

Text (MiniLM): exact repeats (cosine 1.0 up to float error), reworded repeats of one event
and different events of one robot's log, so the same bar can be read against text.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: share of moving pairs the bar may merge (a change thinned away is a lost event)
MOVING_BUDGET = 0.01
#: adjacent pairs in the lowest (highest) quantile of frame change are "still" ("moving")
STILL_Q = 0.2
SUBSETS = ("weights_lite", "blindfolded_lite_train")

#: (event, rewording) pairs: one event logged twice in other words
REWORDED = [
    ("the gripper is holding the red mug", "gripper holding the red mug"),
    ("battery at 80 percent", "battery level is 80 percent"),
    ("door to the kitchen is open", "the kitchen door is open"),
    ("robot parked at the charging dock", "robot is parked at the charging dock"),
    ("picked up the screwdriver from the bench", "picked the screwdriver up from the bench"),
    ("no person in view", "nobody in view"),
    ("conveyor belt stopped", "the conveyor belt has stopped"),
    ("placed the box on shelf 3", "box placed on shelf 3"),
]
#: different events of the same log (must never be merged)
DIFFERENT = [
    "the gripper is holding the red mug",
    "the gripper released the red mug",
    "battery at 80 percent",
    "battery at 20 percent",
    "door to the kitchen is open",
    "door to the kitchen is closed",
    "robot parked at the charging dock",
    "robot left the charging dock",
    "picked up the screwdriver from the bench",
    "picked up the hammer from the bench",
    "conveyor belt stopped",
    "conveyor belt started",
]


def touch_pairs(stag: Path) -> dict[str, np.ndarray]:
    """Cosines of adjacent window pairs (still, moving) and of different-object pairs."""
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.settings import Settings
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.windows import cut_windows
    from tactus_memory.training.stag_io import read_mat_fields

    cfg = Settings()
    enc = TactusEncoder()
    cos_adj: list[float] = []
    motion: list[float] = []
    held: list[tuple[int, np.ndarray]] = []  # (object, one window's z) per recording
    for subset in SUBSETS:
        fields = read_mat_fields(stag / subset / "metadata.mat")
        pressure = np.asarray(fields["pressure"])  # (N, 32, 32) int16 raw
        rec = np.asarray(fields["recordingId"]).reshape(-1).astype(np.int64)
        obj = np.asarray(fields["objectId"]).reshape(-1).astype(np.int64)
        ts = np.asarray(fields["ts"]).reshape(-1).astype(np.float64)
        for r in np.unique(rec):
            idx = np.flatnonzero(rec == r)
            w = cut_windows(pressure[idx], ts[idx], window=cfg.window, stride=cfg.stride)
            w = w.take(~w.idle)  # idle windows are never stored (the touch sense refuses them)
            if len(w) < 2:
                continue
            z = enc.embed(w.frames.astype(np.float32), calibrated=False)  # (Wn, D) unit rows
            mean = STAG_GLOVE.scale(w.frames).mean(axis=1)  # (Wn, 32, 32) calibrated
            adjacent = np.flatnonzero(np.diff(w.start) == cfg.stride)  # no idle gap between
            cos_adj += [float(z[j] @ z[j + 1]) for j in adjacent]
            motion += [float(np.abs(mean[j + 1] - mean[j]).mean()) for j in adjacent]
            held.append((int(obj[idx[0]]), z[len(w) // 2]))
    cos, mot = np.asarray(cos_adj), np.asarray(motion)
    lo, hi = np.quantile(mot, [STILL_Q, 1 - STILL_Q])
    other = [
        float(za @ zb)
        for i, (a, za) in enumerate(held)
        for b, zb in held[i + 1 :]
        if a != b and a != 0 and b != 0  # class 0 is the empty hand
    ]
    return {
        "still": cos[mot <= lo],
        "moving": cos[mot >= hi],
        "all_adjacent": cos,
        "different_objects": np.asarray(other),
    }


def text_pairs() -> dict[str, np.ndarray]:
    from tactus_memory.spaces.minilm import MiniLMSpace

    space = MiniLMSpace()
    a = space.embed_texts([x for x, _ in REWORDED])
    b = space.embed_texts([y for _, y in REWORDED])
    again = space.embed_texts([x for x, _ in REWORDED])
    d = space.embed_texts(DIFFERENT)
    sims = d @ d.T
    off = sims[np.triu_indices(len(DIFFERENT), 1)]
    return {
        "exact_repeat": np.einsum("nd,nd->n", a, again),
        "reworded": np.einsum("nd,nd->n", a, b),
        "different_events": off,
    }


def summary(x: np.ndarray) -> dict[str, float | int]:
    q = np.quantile(x, [0.01, 0.05, 0.5, 0.95, 0.99]) if x.size else [math.nan] * 5
    return {
        "n": int(x.size),
        **{
            k: round(float(v), 4)
            for k, v in zip(("p01", "p05", "median", "p95", "p99"), q, strict=True)
        },
        "max": round(float(x.max()), 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/thinning.json")
    args = ap.parse_args()
    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    t0 = time.perf_counter()
    touch = touch_pairs(stag)
    text = text_pairs()
    worst_change = max(
        float(np.quantile(touch[k], 1 - MOVING_BUDGET)) for k in ("moving", "different_objects")
    )
    bar = math.ceil(float(worst_change) / 0.005) * 0.005
    out = {
        "what": "cosine of adjacent touch windows held still vs moving (STAG weights_lite + "
        "blindfolded_lite_train, shipped checkpoint, service window/stride) and of MiniLM "
        "text repeats",
        "command": "python benchmarks/thinning.py",
        "moving_budget": MOVING_BUDGET,
        "thin_cosine": round(bar, 4),
        "touch": {k: summary(v) for k, v in touch.items()},
        "touch_still_thinned_share": round(float((touch["still"] >= bar).mean()), 4),
        "touch_moving_merged_share": round(float((touch["moving"] >= bar).mean()), 4),
        "touch_different_objects_merged_share": round(
            float((touch["different_objects"] >= bar).mean()), 4
        ),
        "text": {k: summary(v) for k, v in text.items()},
        "text_reworded_thinned_share": round(float((text["reworded"] >= bar).mean()), 4),
        "text_exact_thinned_share": round(float((text["exact_repeat"] >= bar).mean()), 4),
        "text_different_merged_share": round(float((text["different_events"] >= bar).mean()), 4),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
