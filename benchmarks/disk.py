"""Disk benchmark: on-disk bytes vs live bytes while a memory ingests a stream (issue 11).

A writer appends touch-sized rows one commit each, like a glove stream served today (a 384-d
vector + the raw window, 8x32x32 int16 npy bytes ~16 KB), with a text note every
``--text-every`` windows, through ``Memory.add`` (so the memory's own background maintenance
runs, every ``compact_every`` = 64 appends). Every ``--sample`` seconds the items table is
measured: bytes on disk (everything under the table's folder), live bytes (data, deletion
and index files the latest version references), versions kept, fragments, rows.

Policies (``--policy``):
  legacy  what the store did before issue 11: LanceDB ``optimize(cleanup_older_than=1 h)``
          every 64 appends (compacts every fragment under 1M rows, i.e. the whole table)
  tiered  ``tactus_memory.storage.compaction`` (size-tiered compaction, incremental index refresh,
          versions removed once superseded ``retain_seconds`` ago)

The embedder is a stand-in (random unit vectors): disk use depends on row sizes and commit
pattern, not on the encoder, and the 2 shared cores are kept for the writer.

    python benchmarks/disk.py --seconds 180 --policy both     # JSON: benchmarks/results/disk.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# the 384-d stand-in space of memory.py: a fresh random unit vector per text (as before)
from memory import DIM, BenchSpace  # noqa: E402
from tactus_memory.memory.main import Memory  # noqa: E402
from tactus_memory.policies import MaintenanceConfig  # noqa: E402
from tactus_memory.senses.base import Sense, array_to_bytes  # noqa: E402
from tactus_memory.storage.disk import dir_bytes, footprint  # noqa: E402

WINDOW = (8, 32, 32)  # K frames x 32 x 32 taxels, int16 STAG units (a touch row's raw bytes)


class RawTouchSense(Sense):
    """A touch sense storing the raw window like TactusEncoder does, with a stand-in vector."""

    name = "touch"
    modality = "touch"
    dim = DIM

    def __init__(self) -> None:
        self.rng = np.random.default_rng(1)

    def validate(self, item: Any) -> np.ndarray:
        return np.asarray(item, dtype=np.int16).reshape(WINDOW)

    def embed(self, batch: Sequence[Any]) -> np.ndarray:
        v = self.rng.standard_normal((len(batch), DIM)).astype(np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def to_row(self, item: Any) -> dict[str, Any]:
        return {"raw": array_to_bytes(item)}


class LegacyMaintainer:
    """The pre-issue-11 policy: LanceDB optimize (full compaction) + 1 h version retention."""

    def __init__(self, table: Any) -> None:
        self.table = table

    def run(self) -> list[Any]:
        self.table.optimize(cleanup_older_than=timedelta(hours=1))
        return []


def run_policy(policy: str, args: argparse.Namespace, root: str) -> dict[str, Any]:
    path = os.path.join(root, policy)
    cfg = MaintenanceConfig(maintain=True, retain_seconds=args.retain)
    mem = Memory.open(path, BenchSpace(), maintenance=cfg)
    mem.add_sense(RawTouchSense())
    if policy == "legacy":
        legacy = LegacyMaintainer(mem.store.items)
        mem.store.maintainer = lambda: legacy  # type: ignore[method-assign]
    table_path = os.path.join(path, "items.lance")
    rng = np.random.default_rng(2)
    window = rng.integers(480, 1100, size=WINDOW, dtype=np.int16)  # STAG-like raw values
    stop = threading.Event()
    written = {"touch": 0, "text": 0, "errors": 0}
    commit_ms: list[float] = []

    def writer() -> None:
        period = 1.0 / args.rate
        t_next = time.perf_counter()
        i = 0
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                noisy = window + rng.integers(-20, 20, size=WINDOW, dtype=np.int16)
                mem.add("glove", "touch", noisy, t=i / 30.0 * 8, source="glove-l")
                written["touch"] += 1
                if args.text_every and i % args.text_every == 0:
                    mem.add("glove", "text", f"note {i}: the operator moves the mug", t=i)
                    written["text"] += 1
            except Exception as exc:  # noqa: BLE001  (a benchmark counts and goes on)
                written["errors"] += 1
                print(f"write error: {exc}", file=sys.stderr)
            commit_ms.append((time.perf_counter() - t0) * 1000)
            i += 1
            t_next += period
            time.sleep(max(0.0, t_next - time.perf_counter()))

    thread = threading.Thread(target=writer, daemon=True)
    t_start = time.perf_counter()
    thread.start()
    samples = []
    while time.perf_counter() - t_start < args.seconds:
        time.sleep(args.sample)
        fp = footprint(table_path)
        samples.append(
            {
                "t": round(time.perf_counter() - t_start, 1),
                "disk_bytes": fp.disk_bytes,
                "live_bytes": fp.live_bytes,
                "ratio": round(fp.ratio, 3),
                "versions": fp.versions,
                "fragments": fp.fragments,
                "rows": fp.rows,
                "store_bytes": dir_bytes(path),
            }
        )
        s = samples[-1]
        print(
            f"[{policy}] t={s['t']:6.1f}s rows={s['rows']:6d} live={s['live_bytes'] / 1e6:7.1f}MB "
            f"disk={s['disk_bytes'] / 1e6:7.1f}MB ratio={s['ratio']:5.2f} "
            f"versions={s['versions']:5d} fragments={s['fragments']:4d}",
            flush=True,
        )
    stop.set()
    thread.join()
    mem.wait_for_maintenance(120)
    mem.store.wait_for_cleanup(120)
    late = [s for s in samples if s["t"] >= args.warmup]
    ratios = [s["ratio"] for s in late] or [s["ratio"] for s in samples]
    out = {
        "policy": policy,
        "retain_seconds": args.retain if policy == "tiered" else 3600,
        "written": written,
        "commit_ms_p50": round(statistics.median(commit_ms), 2) if commit_ms else None,
        "commit_ms_p95": round(float(np.percentile(commit_ms, 95)), 2) if commit_ms else None,
        "final": samples[-1] if samples else None,
        "ratio_max_after_warmup": max(ratios),
        "ratio_mean_after_warmup": round(statistics.mean(ratios), 3),
        "ratio_last": samples[-1]["ratio"] if samples else None,
        "versions_max": max(s["versions"] for s in samples) if samples else None,
        "samples": samples,
    }
    shutil.rmtree(path, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=180.0, help="streaming time per policy")
    ap.add_argument("--policy", choices=["legacy", "tiered", "both"], default="both")
    ap.add_argument("--rate", type=float, default=30.0, help="touch windows per second (cap)")
    ap.add_argument("--text-every", type=int, default=10, help="a text note every N windows")
    ap.add_argument("--retain", type=float, default=MaintenanceConfig().retain_seconds)
    ap.add_argument("--sample", type=float, default=5.0, help="seconds between measurements")
    ap.add_argument("--warmup", type=float, default=30.0, help="ratio stats start after this")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "disk.json"))
    ap.add_argument("--dir", default=None, help="where the stores go (default: a temp dir)")
    ap.add_argument("--label", default=None, help="result key (default: the policy name)")
    args = ap.parse_args()
    root = tempfile.mkdtemp(prefix="tactus-disk-", dir=args.dir)
    policies = ["legacy", "tiered"] if args.policy == "both" else [args.policy]
    out_path = Path(args.out)
    result: dict[str, Any] = {}
    for policy in policies:
        key = args.label or policy
        run = run_policy(policy, args, root) | {"args": vars(args)}
        # merge into the file as it is now (another run may have written meanwhile)
        result = json.loads(out_path.read_text()) if out_path.exists() else {}
        result.setdefault("policies", {})[key] = run
        result["machine"] = {"cpus": os.cpu_count(), "platform": platform.platform()}
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(json.dumps(result, indent=1))
    shutil.rmtree(root, ignore_errors=True)
    for policy, r in result["policies"].items():
        print(
            f"{policy}: ratio max {r['ratio_max_after_warmup']} (after {args.warmup:.0f}s), "
            f"last {r['ratio_last']}, versions max {r['versions_max']}"
        )


if __name__ == "__main__":
    main()
