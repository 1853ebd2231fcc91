"""The caption's firmness bands (issue 50): quartiles of the sensor-relative force of the STAG
glove's blindfolded recordings (objects handled), one of the shipped checkpoint's two training
subsets.

A window's *pressure* is its ``force`` over the sensor's taxels (the mean calibrated reading,
``touch.facets.pressure``). The STAG glove's windows are cut as the memory stores them
(``stream_eval.build_stream``: 8 frames every 4, idle ones dropped) from the blindfolded
recordings; the pressure is computed here from the raw
frames and the 548 public taxel coordinates (the calibration written out, not the facets
module). ``touch.facets.LIGHT_PRESSURE`` and ``FIRM_PRESSURE`` are the 25th and 75th
percentiles, rounded to 4 decimals. The weights subset (the checkpoint's other training
subset: the glove holding weights, another day) is reported beside it: its windows sit higher
(pedestal and load), so by these bands all of them are "firm".

    TACTUS_DATA_HOME=... python benchmarks/firmness_bands.py   # results/firmness_bands.json
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tactus_memory.datasets.home import data_home
from tactus_memory.touch.facets import FIRM_PRESSURE, LIGHT_PRESSURE
from tactus_memory.training import stream_eval
from tactus_memory.training.data import load_stag

OUT = Path(__file__).parent / "results" / "firmness_bands.json"
SUBSETS = {"objects": "blindfolded_lite_train", "weights": "weights_lite"}


def pressures(subset: Path, coords: np.ndarray) -> np.ndarray:
    """(N,) the stored windows' mean calibrated taxel reading, N windows of every recording."""
    d = load_stag(subset / "metadata.mat")
    out: list[float] = []
    for r in np.unique(d.recording_id):
        s = stream_eval.build_stream(d, [int(r)])
        keep = np.flatnonzero(~s.idle)
        if len(keep) < 2:  # as benchmarks/facet_questions.py: a recording of >= 2 windows
            continue
        raw = s.frames[keep].astype(np.float64)[:, :, coords[:, 0], coords[:, 1]]  # (n, K, 548)
        cal = np.clip((raw - 500.0) / 150.0, 0.0, 1.0)  # STAG_GLOVE: clip((raw-500)/150, 0, 1)
        out.extend(cal.mean(axis=2).mean(axis=1).tolist())
    return np.asarray(out)


def main() -> None:
    stag = data_home().stag
    cj = json.loads((stag / "sensor_coords.json").read_text())
    coords = np.array(list(zip(cj["x"], cj["y"], strict=True)))
    result: dict = {"what": "pressure (force / taxels) quartiles of stored STAG windows"}
    for name, subset in SUBSETS.items():
        p = pressures(stag / subset, coords)
        q = np.percentile(p, [25, 50, 75])
        result[name] = {
            "subset": subset,
            "windows": len(p),
            "p25": round(float(q[0]), 4),
            "p50": round(float(q[1]), 4),
            "p75": round(float(q[2]), 4),
            "share_light": round(float(np.mean(p < LIGHT_PRESSURE)), 3),
            "share_firm": round(float(np.mean(p >= FIRM_PRESSURE)), 3),
        }
    result["bands"] = {"light_below": LIGHT_PRESSURE, "firm_from": FIRM_PRESSURE}
    result["bands_are_objects_quartiles"] = (
        result["bands"]["light_below"] == result["objects"]["p25"]
        and result["bands"]["firm_from"] == result["objects"]["p75"]
    )
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
