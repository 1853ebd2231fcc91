"""The prior score calibration of each shipped touch checkpoint (``search/scoring.py``).

    python benchmarks/calibration_prior.py [--out benchmarks/results/calibration_prior.json]

For each shipped checkpoint (the default and the demo one): every recording of the STAG
``weights_lite`` and ``blindfolded_lite_train`` subsets cut by the stream windowing (idle
windows not stored), the first ``scoring.SAMPLE`` contact windows (evenly spaced over all of
them) stored in a real memory (real MiniLM, real LanceDB), and the sense's own calibration
estimated there (the probe bank against those windows): the null a memory full of grasps
ends with. Written, keyed by checkpoint sha256, to
``tactus_memory/touch/checkpoints/calibration-priors.json`` (means and deviations only; no
data) and to ``--out``. STAG: ``$TACTUS_STAG_DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/calibration_prior.json")
    args = ap.parse_args()
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.search.scoring import SAMPLE
    from tactus_memory.touch.checkpoint import (
        CALIBRATION_PRIORS,
        default_checkpoint_path,
        demo_checkpoint_path,
    )
    from tactus_memory.training.stream_eval import build_stream
    from tactus_memory.training.train import load_data

    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    stream = build_stream(data, [int(r) for r in np.unique(data.recording_id)])
    contact = np.flatnonzero(~stream.idle)
    pick = contact[np.linspace(0, len(contact) - 1, min(SAMPLE, len(contact))).astype(int)]
    priors = {}
    for path in (default_checkpoint_path(), demo_checkpoint_path()):
        enc = TactusEncoder(path)
        with tempfile.TemporaryDirectory() as tmp:
            mem = Memory.open(str(Path(tmp) / "m"), background=False)
            mem.add_sense(enc)
            mem.add_many(
                "prior", "touch", list(stream.frames[pick]),
                t=stream.t[pick].tolist(), t_end=stream.t_end[pick].tolist(),
            )  # fmt: skip
            c = mem.registry.own_calibration("touch")
            mem.close()
        priors[enc.ckpt.sha256] = {
            "checkpoint": path.name,
            "mu": c.mu,
            "sigma": c.sigma,
            "windows": c.n,
        }
        print(path.name, priors[enc.ckpt.sha256], flush=True)
    doc = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/calibration_prior.py",
        "contact_windows": int(len(contact)),
        "priors": priors,
    }
    text = json.dumps(doc, indent=1) + "\n"
    (default_checkpoint_path().parent / CALIBRATION_PRIORS).write_text(text)
    args.out.write_text(text)


if __name__ == "__main__":
    main()
