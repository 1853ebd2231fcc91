"""The idle rule on a coarser sensor: the contact level estimated from its own training grasps.

    python benchmarks/contact_level.py [--out benchmarks/results/contact_level.json]

A derived 16x16 sensor: every glove frame 2x2 mean-pooled in raw units (the glove's offset and
span calibrate it; no taxel mask). The protocol's fold A: the contact level of the 16x16
sensor is estimated (``touch.windows.estimate_contact_level``, what ``tactus train`` records
for a sensor other than the glove) from the labelled frames of the training recordings only;
the 26 held-out recordings are then cut by the stream windowing (K = 8, stride 4) three ways:
the 32x32 glove at its level (1/6), the 16x16 sensor at the glove's fixed level (the rule
before), and the 16x16 sensor at its estimated level. Per way: the share of *held* windows
(windows holding a labelled grasp frame) kept, and the share of the other windows kept (the
idle rule's other side). STAG: ``$TACTUS_STAG_DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HOLDOUT = "one-per-object@blindfolded"
WINDOW, STRIDE = 8, 4  # the stream evaluation's windowing


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/contact_level.json")
    args = ap.parse_args()
    from dataclasses import replace

    from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile
    from tactus_memory.touch.windows import (
        CONTACT_LEVEL,
        contact_level,
        cut_windows,
        estimate_contact_level,
    )
    from tactus_memory.training.train import holdout_recordings, load_data

    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    raw16 = data.pressure.astype(np.float32).reshape(-1, 16, 2, 16, 2).mean(axis=(2, 4))
    coarse = SensorProfile(
        name="glove-16x16", offset=STAG_GLOVE.offset, span=STAG_GLOVE.span, shape=(16, 16)
    )
    held = holdout_recordings(data, HOLDOUT)
    train = ~np.isin(data.recording_id, held)
    level16 = estimate_contact_level(coarse.scale(raw16[data.valid & train]))
    level32 = estimate_contact_level(STAG_GLOVE.scale(data.pressure[data.valid & train]))
    ways = {
        "glove_32x32": (data.pressure, STAG_GLOVE),
        "16x16_glove_level": (raw16, coarse),
        "16x16_estimated_level": (raw16, replace(coarse, contact_level=level16)),
    }
    out: dict = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/contact_level.py",
        "heldout_recordings": len(held),
        "estimated_level": {"16x16": level16, "32x32_same_rule": level32, "glove": CONTACT_LEVEL},
    }
    for name, (frames, profile) in ways.items():
        kept_held = n_held = kept_other = n_other = 0
        for r in held:
            m = np.flatnonzero(data.recording_id == r)
            m = m[np.argsort(data.frame[m], kind="stable")]
            ts = data.ts[m] - data.ts[m].min()
            w = cut_windows(frames[m], ts, window=WINDOW, stride=STRIDE, profile=profile)
            lab = np.array([data.valid[m[s : s + WINDOW]].any() for s in w.start], bool)
            kept = ~w.idle
            kept_held += int((kept & lab).sum())
            n_held += int(lab.sum())
            kept_other += int((kept & ~lab).sum())
            n_other += int((~lab).sum())
        out[name] = {
            "contact_level": contact_level(profile),
            "held_windows": n_held,
            "held_kept": kept_held,
            "held_kept_share": kept_held / n_held,
            "other_windows": n_other,
            "other_kept_share": kept_other / n_other,
            "all_kept": kept_held + kept_other,
            "all_windows": n_held + n_other,
        }
        print(name, out[name], flush=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
