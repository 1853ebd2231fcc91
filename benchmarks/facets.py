"""What touch facets cost: window facets (tactus_memory/touch/facets.py) for a fleet of 64 STAG
gloves at 30 Hz, windows of 8 frames every 4 (7.5 windows a second a glove: 480 a second).

Two paths are timed on real STAG windows (the blindfolded subset when present, else the
weights subset; synthetic frames when neither is): one batch of the 480 windows of a second
(``window_facets`` on (480, 8, 32, 32)), and the write path's window by window (each window's
facets and its store columns, as ``TactusEncoder.to_row`` computes them). CPU seconds of the
process (``time.process_time``), median and range over the repeats; ``core_share`` is the
fraction of one core a second of the fleet's windows costs.

    nice python benchmarks/facets.py            # writes benchmarks/results/facets.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from tactus_memory.touch.facets import facet_columns, window_facets
from tactus_memory.touch.profile import STAG_GLOVE

GLOVES, HZ, WINDOW, STRIDE = 64, 30.0, 8, 4
WINDOWS_PER_S = int(GLOVES * HZ / STRIDE)  # 480
OUT = Path(__file__).parent / "results" / "facets.json"


def real_windows(n: int) -> tuple[np.ndarray, str]:
    """n calibrated (8, 32, 32) windows cut from a real STAG file, or synthetic ones."""
    from tactus_memory.datasets.home import data_home
    from tactus_memory.training.data import load_stag

    for subset in ("blindfolded_lite_train", "blindfolded_lite", "weights_lite"):
        path = data_home().stag / subset / "metadata.mat"
        if path.is_file():
            d = load_stag(path)
            starts = np.linspace(0, d.n_frames - WINDOW, n).astype(int)
            raw = np.stack([d.pressure[s : s + WINDOW] for s in starts])
            return STAG_GLOVE.calibrate(raw), f"STAG {subset}"
    rng = np.random.default_rng(0)
    return rng.uniform(0.05, 0.4, (n, WINDOW, 32, 32)).astype(np.float32), "synthetic"


def cpu_seconds(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        out.append(time.process_time() - t0)
    return out


def summary(seconds: list[float], windows: int) -> dict[str, float]:
    med = statistics.median(seconds)
    return {
        "cpu_s_per_fleet_second_median": round(med, 5),
        "cpu_s_min": round(min(seconds), 5),
        "cpu_s_max": round(max(seconds), 5),
        "us_per_window_median": round(med / windows * 1e6, 2),
        "core_share": round(med, 4),  # CPU seconds per second of the fleet's windows
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    wins, source = real_windows(WINDOWS_PER_S)
    batch = cpu_seconds(lambda: window_facets(wins, STAG_GLOVE), args.repeats)

    def one_by_one() -> None:
        for w in wins:
            facet_columns(window_facets(w[None], STAG_GLOVE).row(0))

    single = cpu_seconds(one_by_one, args.repeats)
    result = {
        "what": "touch facets per window, 64 STAG gloves at 30 Hz (8-frame windows every 4)",
        "windows_per_second": WINDOWS_PER_S,
        "data": source,
        "repeats": args.repeats,
        "batch": summary(batch, WINDOWS_PER_S),
        "write_path_one_by_one": summary(single, WINDOWS_PER_S),
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or "?"},
    }
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
