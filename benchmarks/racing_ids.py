"""Racing ids (issue 48, defect 3; issue 29): other writers' throughput while two pairs of
clients keep writing the same ids inside the group commit's ticks.

In one process on a real LanceDB store (pre-filled with ``--rows`` text rows, so a
merge-insert's join over every stored ``id`` costs what it does in a store in use), a
:class:`GroupCommitter` (tick 25 ms, the server's) takes writes from ``--writers`` threads,
each submitting one vector of a vector sense at a time (a 384-d stand-in space,
``memory.BenchSpace``: the embedding is not under test, the commit path is) and from two pairs
of racer threads, each pair re-sending one note with one explicit id. Measured: the other
writers' writes/s over ``--seconds``, alone and with the racers, in interleaved rounds
(alone, racing, alone, racing ...); reported the per-round ratio racing/alone and its mean
with a 95 % t interval, and the store commits of each kind the racing runs made.

The code under test is the interpreter's checkout: run it with another checkout's
interpreter (``--python``-free: ``/other/.venv/bin/python benchmarks/racing_ids.py``) for the
code before a change.

    python benchmarks/racing_ids.py --rounds 3 --seconds 8
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats as st

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from load import run_header  # noqa: E402
from memory import DIM, BenchSpace  # noqa: E402
from tactus_memory.adapters.vectors import VectorSense  # noqa: E402
from tactus_memory.errors import TactusError  # noqa: E402
from tactus_memory.memory.group_commit import GroupCommitter  # noqa: E402
from tactus_memory.memory.main import Memory  # noqa: E402


def run(memory: Any, writers: int, racers: bool, seconds: float) -> dict[str, Any]:
    stop = threading.Event()
    done = [0] * writers
    kinds: dict[str, int] = {"append": 0, "merge": 0}
    real = memory.store.write

    def counted(data: Any, *, upsert: bool) -> None:
        kinds["merge" if upsert else "append"] += 1
        real(data, upsert=upsert)

    memory.store.write = counted
    rng = np.random.default_rng(0)
    vecs = rng.standard_normal((16, DIM)).astype(np.float32)
    with GroupCommitter(memory, tick=0.025) as gc:

        def writer(i: int) -> None:
            n = 0
            while not stop.is_set():
                gc.submit(f"w{i}", "motion", [vecs[n % 16]], t=[float(n)]).result()
                n += 1
                done[i] += 1

        def racer(pair: int) -> None:
            while not stop.is_set():
                with contextlib.suppress(TactusError):
                    gc.submit(f"att{pair}", "text", ["x"], t=[1.0], ids=[f"a{pair}-1"]).result()

        threads = [threading.Thread(target=writer, args=(i,)) for i in range(writers)]
        if racers:
            threads += [threading.Thread(target=racer, args=(p,)) for p in (0, 0, 1, 1)]
        for th in threads:
            th.start()
        time.sleep(seconds)
        start = sum(done)
        t0 = time.monotonic()
        time.sleep(seconds)
        rate = (sum(done) - start) / (time.monotonic() - t0)
        stop.set()
        for th in threads:
            th.join()
    memory.store.write = real
    return {"windows_per_s": round(rate, 1), "commits": kinds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=10_000)
    ap.add_argument("--writers", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=8.0, help="warm-up, then measured, each")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--label", default="")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "racing_ids.json"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tactus-racing-") as tmp:
        memory = Memory.open(str(Path(tmp) / "mem"), space=BenchSpace())
        memory.add_sense(VectorSense("motion", dim=DIM))
        for b in range(0, args.rows, 2500):
            n = min(2500, args.rows - b)
            memory.add_many("bulk", "text", [f"note {b + i}" for i in range(n)], t=[0.0] * n)
        rounds = []
        for r in range(args.rounds):
            alone = run(memory, args.writers, False, args.seconds)
            racing = run(memory, args.writers, True, args.seconds)
            ratio = racing["windows_per_s"] / alone["windows_per_s"]
            rounds.append({"round": r, "alone": alone, "racing": racing, "ratio": round(ratio, 3)})
            print(json.dumps(rounds[-1]), flush=True)
    ratios = np.array([x["ratio"] for x in rounds])
    mean = float(ratios.mean())
    half = float(st.t.ppf(0.975, len(ratios) - 1) * ratios.std(ddof=1) / np.sqrt(len(ratios)))
    out = {
        **run_header("racing_ids"),
        "label": args.label,
        "config": {k: v for k, v in vars(args).items() if k != "out"},
        "rounds": rounds,
        "ratio_mean": round(mean, 3),
        "ratio_ci95": [round(mean - half, 3), round(mean + half, 3)],
    }
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({k: out[k] for k in ("label", "ratio_mean", "ratio_ci95")}))


if __name__ == "__main__":
    main()
