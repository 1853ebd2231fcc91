"""The touch encoder beside a busy Python thread (issue 28): why a server's event loop slows
its group committer. The shipped TactusEncoder embeds batches of ``--batch`` raw windows on one
torch thread for ``--seconds`` per case, ``--rounds`` times in turn:

* ``alone``: nothing else runs in this process;
* ``beside_busy_thread``: a thread spins in pure Python meanwhile (as an event loop reading
  ~2,000 WebSocket frames/s does), so each torch call of the encoder waits for the
  interpreter lock when it returns;
* ``process_beside_busy_thread``: the same busy thread, the batches embedded by
  :class:`tactus_memory.memory.encode_process.EncoderProcess` (a worker process, its own lock).

Reported per case: windows/s, and the CPU share of the embedding thread (its CPU seconds over
wall seconds; low = waiting for the lock or for a core; in the process case it only waits),
with the 1-minute load average.

    python benchmarks/encoder_gil.py          # ~1 min; benchmarks/results/encoder_gil.json
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from pathlib import Path

import numpy as np

from load import run_header

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "encoder_gil.json"))
    args = ap.parse_args()
    import torch

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.encode_process import EncoderProcess

    torch.set_num_threads(1)
    enc = TactusEncoder()
    rng = np.random.default_rng(0)
    raw = (500 + 200 * rng.random((args.batch, 8, 32, 32))).astype(np.uint16)
    wins = [enc.validate(w) for w in raw]
    worker = EncoderProcess(("touch",), threads=1)
    while not worker.ready:
        time.sleep(0.1)
    busy = threading.Event()
    done = threading.Event()

    def spin() -> None:
        x = 0
        while not done.is_set():
            if busy.is_set():
                for i in range(1000):
                    x += i
            else:
                time.sleep(0.01)

    threading.Thread(target=spin, daemon=True).start()
    cases = {
        "alone": (False, enc.embed),
        "beside_busy_thread": (True, enc.embed),
        "process_beside_busy_thread": (True, lambda ws: worker.embed(enc, ws)),
    }
    result = {**run_header("encoder_gil"), "batch": args.batch, "seconds": args.seconds}
    result["runs"] = []
    for _ in range(args.rounds):
        for name, (spinning, embed) in cases.items():
            busy.set() if spinning else busy.clear()
            embed(wins)
            n, t0, c0 = 0, time.perf_counter(), time.thread_time()
            while time.perf_counter() - t0 < args.seconds:
                embed(wins)
                n += len(wins)
            wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
            run = {"case": name, "windows_per_s": round(n / wall, 1)}
            run.update(cpu_share=round(cpu / wall, 2), load1=round(os.getloadavg()[0], 2))
            result["runs"].append(run)
            print(json.dumps(run), flush=True)
    done.set()
    worker.close()
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
