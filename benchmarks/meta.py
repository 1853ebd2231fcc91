"""Meta-table size under metadata writes alone (issue 29): 10,000 clock-offset writes and no
item write at all, through ``Memory.set_clock_offset`` (what ``PUT /sessions/{s}/clock``
runs), with the default maintenance policy running as a server runs it (background thread,
``compact_every`` = 64 commits of a table, versions kept 30 s after they are superseded).

Two patterns (``--pattern``):
  new    every write to a new session (the attack: before issue 29, one JSON of every
         session's offsets was rewritten per write and only item writes triggered cleanup:
         1,000 writes left meta.lance at ~16 MB, 3,060 at 141 MB)
  same   writes cycling over ``--sessions`` sessions (a fleet re-syncing its clocks)

Every ``--sample`` writes the meta table is measured: bytes on disk, versions kept, live
bytes (what the latest version references), rows. The run stops after ``--writes`` writes or
``--seconds``. JSON: ``benchmarks/results/meta.json``.

    python benchmarks/meta.py                       # both patterns, 10,000 writes each
    python benchmarks/meta.py --pattern new --writes 2000
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from memory import BenchSpace  # noqa: E402  (no embedding happens here: a stand-in space)
from tactus_memory.memory.main import Memory  # noqa: E402
from tactus_memory.storage.disk import footprint  # noqa: E402

MiB = 1024 * 1024


def run(pattern: str, writes: int, sessions: int, sample: int, seconds: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="tactus-meta-") as tmp:
        memory = Memory.open(tmp + "/mem", space=BenchSpace())
        meta = Path(tmp) / "mem" / "meta.lance"
        samples: list[dict[str, Any]] = []
        t0 = time.perf_counter()
        done = 0
        while done < writes and time.perf_counter() - t0 < seconds:
            session = f"s{done}" if pattern == "new" else f"s{done % sessions}"
            memory.set_clock_offset(session, "touch", 1.0 + done % 97, source="glove")
            done += 1
            if done % sample == 0 or done == writes:
                fp = footprint(str(meta))
                samples.append(
                    {
                        "writes": done,
                        "seconds": round(time.perf_counter() - t0, 1),
                        "disk_mb": round(fp.disk_bytes / MiB, 2),
                        "live_mb": round(fp.live_bytes / MiB, 3),
                        "versions": fp.versions,
                        "fragments": fp.fragments,
                        "rows": fp.rows,
                    }
                )
                print(json.dumps({"pattern": pattern, **samples[-1]}), flush=True)
        elapsed = time.perf_counter() - t0
        memory.close()
        assert len(memory.clock_offsets()) == (done if pattern == "new" else min(done, sessions))
    disk = [s["disk_mb"] for s in samples]
    half = [s["disk_mb"] for s in samples if s["writes"] > done // 2]
    return {
        "pattern": pattern,
        "writes": done,
        "sessions": done if pattern == "new" else sessions,
        "writes_per_s": round(done / elapsed, 1),
        "disk_mb_max": max(disk),
        "disk_mb_end": disk[-1],
        "disk_mb_max_second_half": max(half) if half else None,
        "versions_max": max(s["versions"] for s in samples),
        "samples": samples,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pattern", choices=["new", "same", "both"], default="both")
    ap.add_argument("--writes", type=int, default=10_000)
    ap.add_argument("--sessions", type=int, default=100, help="sessions of --pattern same")
    ap.add_argument("--sample", type=int, default=500, help="measure every this many writes")
    ap.add_argument("--seconds", type=float, default=240, help="longest one pattern runs")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/meta.json")
    args = ap.parse_args()
    patterns = ["new", "same"] if args.pattern == "both" else [args.pattern]
    runs = [run(p, args.writes, args.sessions, args.sample, args.seconds) for p in patterns]
    report = {
        "benchmark": "meta",
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "command": "python benchmarks/meta.py " + " ".join(sys.argv[1:]),
        "runs": runs,
    }
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    for r in runs:
        print({k: v for k, v in r.items() if k != "samples"})


if __name__ == "__main__":
    main()
