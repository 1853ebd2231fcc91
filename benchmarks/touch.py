"""Touch encoder CPU latency/throughput: every config, eager vs channels_last vs torch.compile.

    python benchmarks/touch.py [--threads 1 2] [--compile] [--out benchmarks/results/touch.json]

Measures, per config (random weights; speed does not depend on them):
  * p50 / p90 ms per window at batch 1 (one K=8 window of 32x32 frames),
  * windows/s at batch 64,
under ``torch.inference_mode``. Also the shipped checkpoint through ``TactusEncoder.embed``
(numpy in, validation + calibration of raw int16 windows included). The machine is shared, so
the load average is recorded next to the figures. Targets for the CPU default on 2 cores:
<= 5 ms/window at batch 1 and >= 500 windows/s at batch 64.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactus_memory.touch.model import create_model, list_models, param_report

ROOT = Path(__file__).resolve().parents[1]


def _time(fn, reps: int, warmup: int = 3) -> list[float]:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def bench_model(model: torch.nn.Module, reps1: int, reps64: int) -> dict[str, float]:
    x1 = torch.rand(1, 8, 32, 32)
    x64 = torch.rand(64, 8, 32, 32)
    with torch.inference_mode():
        t1 = _time(lambda: model(x1), reps1)
        t64 = _time(lambda: model(x64), reps64, warmup=1)
    return {
        "b1_p50_ms": round(1e3 * statistics.median(t1), 3),
        "b1_p90_ms": round(1e3 * float(np.percentile(t1, 90)), 3),
        "b64_windows_per_s": round(64 / statistics.median(t64), 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/touch.json"))
    ap.add_argument("--compile", action="store_true", help="also try torch.compile (slow)")
    args = ap.parse_args()
    res: dict[str, Any] = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "torch_threads": args.threads,
            "torch": torch.__version__,
            "python": platform.python_version(),
            "loadavg_start": os.getloadavg(),
        },
        "targets": {"b1_p50_ms_max": 5.0, "b64_windows_per_s_min": 500.0},
        "models": {},
    }
    for threads in args.threads:
        torch.set_num_threads(threads)
        res["models"][f"threads={threads}"] = run_models(args, threads)
        res["shipped_encoder"] = res.get("shipped_encoder", {})
        res["shipped_encoder"][f"threads={threads}"] = run_shipped()
    res["machine"]["loadavg_end"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print("wrote", args.out)


def run_models(args: argparse.Namespace, threads: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in list_models():
        big = name == "tactus-r18"
        out_dim = 2048 if big else 384
        torch.manual_seed(0)
        m = create_model(name, out_dim).eval()
        row: dict[str, Any] = {"out_dim": out_dim, "params": param_report(m)}
        reps1, reps64 = (10, 2) if big else (60, 10)
        row["eager"] = bench_model(m, reps1, reps64)
        row["channels_last"] = bench_model(m.to(memory_format=torch.channels_last), reps1, reps64)
        m = m.to(memory_format=torch.contiguous_format)
        if args.compile and not big:
            try:
                t = time.perf_counter()
                cm = torch.compile(m)
                with torch.inference_mode():
                    cm(torch.rand(1, 8, 32, 32))
                    cm(torch.rand(64, 8, 32, 32))
                row["compile_s"] = round(time.perf_counter() - t, 1)
                row["torch_compile"] = bench_model(cm, reps1, reps64)
            except Exception as exc:  # noqa: BLE001 - record why compile is unavailable
                row["torch_compile"] = {"error": f"{type(exc).__name__}: {exc}"[:300]}
        print(f"threads={threads}", name, json.dumps(row), flush=True)
        out[name] = row
    return out


def run_shipped() -> dict[str, Any]:
    """The shipped default through the sense API (raw int16 windows, validation included)."""
    try:
        from tactus_memory.adapters.touch import TactusEncoder

        enc = TactusEncoder()
        rng = np.random.default_rng(0)
        raw1 = [rng.integers(505, 700, (8, 32, 32)).astype(np.int16)]
        raw64 = [rng.integers(505, 700, (8, 32, 32)).astype(np.int16) for _ in range(64)]
        t1 = _time(lambda: enc.embed(raw1), 60)
        t64 = _time(lambda: enc.embed(raw64), 10, warmup=1)
        row = {
            "model": enc.provenance()["model"],
            "checkpoint_sha256": enc.ckpt.sha256,
            "b1_p50_ms": round(1e3 * statistics.median(t1), 3),
            "b64_windows_per_s": round(64 / statistics.median(t64), 1),
        }
        print("shipped", row, flush=True)
        return row
    except FileNotFoundError as exc:
        return {"error": str(exc)}


if __name__ == "__main__":
    main()
