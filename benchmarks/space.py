"""The model fingerprint a store records for a space: its cost does not grow with the weights.

    python benchmarks/space.py [--out benchmarks/results/space.json]

A folder with a config.json and one weight file of each size (sparse files: the bytes read
are what matters, 2 MiB per file at most), timed over repeats with a warm page cache (a cold
start adds the disk's time for two 1 MiB reads per file); the target is <= 50 ms at the
Qwen3-VL-Embedding-2B size (~4.3 GB), since every open of a Qwen3-VL memory and every
touch-encoder registration computes it once.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from tactus_memory.spaces.fingerprint import model_fingerprint

ROOT = Path(__file__).resolve().parents[1]
#: the order of Qwen3-VL-Embedding-2B's weights: ~2.1B parameters x 2 bytes (bfloat16); not the
#: released file's exact size (no real weights here), which does not matter: 2 MiB are read
QWEN3VL_2B_BYTES = 4_260_000_000
SIZES = (1 << 20, 100 << 20, QWEN3VL_2B_BYTES)
REPEATS = 20


def time_fingerprint(size: int, repeats: int = REPEATS) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "config.json").write_text(json.dumps({"model_type": "qwen3_vl"}))
        with (folder / "model.safetensors").open("wb") as f:
            f.write(os.urandom(1 << 16))
            f.truncate(size)  # sparse beyond the first 64 KiB
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            model_fingerprint(folder)
            times.append((time.perf_counter() - t0) * 1e3)
    return {
        "bytes": size,
        "ms_p50": round(statistics.median(times), 3),
        "ms_max": round(max(times), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/space.json")
    args = ap.parse_args()
    rows = [time_fingerprint(s) for s in SIZES]
    result = {
        "benchmark": "space fingerprint",
        "repeats": REPEATS,
        "rows": rows,
        "target_ms_2b": 50.0,
        "meets_target": rows[-1]["ms_p50"] <= 50.0,
        "loadavg": os.getloadavg(),
        "platform": platform.platform(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
