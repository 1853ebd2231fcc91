"""How far simple classifiers get on the held-out glove recordings (a data ceiling check).

    python benchmarks/touch_probe.py [--out benchmarks/results/touch_probe.json]

Same split as the touch ladder (``--holdout one-per-object@blindfolded``: 26 held-out
recordings, 130 valid frames; training = the other 53 recordings' valid frames). Per held-out
frame: the class of its nearest training frame (cosine over the 1024 pixels, 1-NN) and a
logistic-regression probe on the pixels (recording-balanced sample weights), on the
calibrated frames as they are and after fixed input shaping (pressure ** gamma, then a
Gaussian blur), with the training pool being all training recordings or only the
blindfolded ones (the held-out condition). Frame-level, so comparable with the encoder's
tuple top-1 (whose tuples hold 5 frames of one recording). STAG: ``$TACTUS_STAG_DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
from sklearn.linear_model import LogisticRegression

ROOT = Path(__file__).resolve().parents[1]
HOLDOUT = "one-per-object@blindfolded"
SHAPINGS = {"raw": (1.0, 0.0), "gamma0.3": (0.3, 0.0), "blur1": (1.0, 1.0)}
SHAPINGS |= {"gamma0.3+blur1": (0.3, 1.0), "gamma0.3+blur1.5": (0.3, 1.5)}


def shaped(frames: np.ndarray, gamma: float, blur: float) -> np.ndarray:
    """frames: (N, 32, 32) calibrated -> (N, 1024) rows through the model's own InputShaping."""
    import torch

    from tactus_memory.touch.model import InputShaping

    with torch.inference_mode():
        x = InputShaping(gamma, blur)(torch.from_numpy(frames[:, None].astype(np.float32)))
    return x.reshape(len(frames), -1).numpy()


def one_nn(x: np.ndarray, labels: np.ndarray, pool: np.ndarray, test: np.ndarray) -> float:
    u = x / np.linalg.norm(x, axis=1, keepdims=True).clip(1e-6)
    pred = labels[pool][(u[test] @ u[pool].T).argmax(axis=1)]
    return float((pred == labels[test]).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/touch_probe.json")
    args = ap.parse_args()
    from tactus_memory.training.train import holdout_recordings, load_data, prepare_data

    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    td = prepare_data(data, holdout_recordings(data, HOLDOUT))
    train, test = np.flatnonzero(td.train_valid), np.flatnonzero(td.heldout_valid)
    blind_src = [i for i, s in enumerate(data.sources) if "blindfolded" in s]
    pools = {"all": train, "blindfolded_only": train[np.isin(data.subset[train], blind_src)]}
    rec = td.recording_id
    results: dict[str, dict[str, float]] = {}
    for name, (gamma, blur) in SHAPINGS.items():
        x = shaped(td.calibrated, gamma, blur)
        row = {f"1nn_{p}": one_nn(x, td.labels, idx, test) for p, idx in pools.items()}
        w = 1.0 / np.bincount(rec[train])[rec[train]]
        probe = LogisticRegression(C=1.0, max_iter=2000)
        probe.fit(x[train], td.labels[train], sample_weight=w * len(train) / w.sum())
        row["logreg_all"] = float(probe.score(x[test], td.labels[test]))
        results[name] = row
        print(name, {k: round(v, 3) for k, v in row.items()}, flush=True)
    out = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/touch_probe.py",
        "heldout_frames": int(test.size),
        "train_frames": {p: int(idx.size) for p, idx in pools.items()},
        "chance": 1.0 / len(td.classes),
        "frame_top1": results,
    }
    args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
