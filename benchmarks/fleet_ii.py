"""Fleet II (issue 28, items 1-2): where the server's time goes under a glove fleet, and
search beside those writes. Real parts only (``tactus serve`` subprocesses on 127.0.0.1, a
fresh store each, the real MiniLM space and the shipped TactusEncoder); the load generator
(``load.stream_gloves``, binary ``.npy`` frames) runs in this
process, on the same cores as the server.

For each ``--gloves`` count and each ``--variants`` entry (``NAME[@PYTHON][:KEY=VALUE,...]``:
the server's interpreter, e.g. another checkout's venv, and environment, so old and new code
or settings run back to back on the same minute, ``--rounds`` times alternating):

1. warm-up: the gloves stream for ``--warmup-seconds`` (not measured);
2. idle search: ``--searchers`` clients search back to back for ``--idle-seconds``;
3. load: the gloves stream for ``--seconds`` while the searchers search; ``--profile``
   samples the server with py-spy meanwhile (``py-spy record --format raw``) and keeps the
   top frames (own time and total time, as a share of the samples) in the JSON;
4. the server is SIGKILLed while the gloves still stream, and every acknowledged window is
   looked up in the store (``acked_rows_lost``).

Reported per run: ack latency (last frame sent -> ``stored``) p50/p95/p99, windows refused
(503) and acknowledged, search p50/p95 idle and under load and their ratio, the server's
and this process's CPU seconds per acknowledged window (far less sensitive to the other
processes on a shared machine than wall times), and the 1-minute load average before and
after each phase.

    python benchmarks/fleet_ii.py --gloves 64 --seconds 60 --profile
    python benchmarks/fleet_ii.py --gloves 64 --rounds 2 --variants \
        old@/path/to/main/.venv/bin/python new new-nice0:TACTUS_COMMIT_NICE=0
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from fleet import (
    Searchers,
    TactusServer,
    acked_during,
    add_search_args,
    add_store_args,
    stored_ids,
    stream_until_killed,
    summary,
)
from load import Barrier, GloveStats, run_header, stream_gloves

WINDOW = 8  # frames per window = stride (the shipped encoder's window)
TOP_FRAMES = 25
TARGETS = dict(ack_p99_ms_64_gloves=100.0, ack_p99_ms_128_gloves=250.0, refused_128_gloves=0)
TARGETS.update(acked_rows_lost=0, search_p95_load_over_idle=3.0)


def load1() -> float:
    return round(os.getloadavg()[0], 2)


def cpu_seconds(pid: int, children: bool = True) -> float:
    """User + system CPU seconds of process ``pid`` (all its threads) and, with ``children``,
    of its live child processes (the server's encoder process) so far."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:  # a child that just ended
        return 0.0
    own = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    if not children:
        return own
    kids = [
        int(c)
        for t in Path(f"/proc/{pid}/task").iterdir()
        for c in (t / "children").read_text().split()
    ]
    return own + sum(cpu_seconds(c) for c in kids)


# ----------------------------------------------------------------------------- profile
class Profiler:
    """``py-spy record`` of the server for one phase (raw collapsed stacks)."""

    def __init__(self, pid: int, seconds: float, out: Path, rate: int) -> None:
        self.out = out
        exe = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
        cmd = [exe, "record", "--pid", str(pid), "--duration", str(int(seconds))]
        cmd += ["--rate", str(rate), "--format", "raw", "--output", str(out), "--nonblocking"]
        cmd += ["--threads"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def finish(self, timeout: float = 60) -> dict[str, Any]:
        try:
            _, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        if not self.out.exists():
            return {"error": err.decode(errors="replace")[-500:]}
        return top_frames(self.out.read_text())


def _frame(name: str) -> str:
    """``func (path/to/module.py:12)`` -> ``func (module.py:12)``; thread roots kept."""
    if " (" not in name:
        return name
    func, where = name.split(" (", 1)
    return f"{func} ({where.rsplit('/', 1)[-1]}"


def top_frames(raw: str, n: int = TOP_FRAMES) -> dict[str, Any]:
    """Collapsed stacks (``thread;outer;...;inner COUNT`` per line) -> the samples, the top
    ``n`` frames by own time (innermost) and by total time (anywhere on the stack), and the
    share of samples per thread, each as a fraction of all samples."""
    own: collections.Counter[str] = collections.Counter()
    total: collections.Counter[str] = collections.Counter()
    threads: collections.Counter[str] = collections.Counter()
    samples = 0
    for line in raw.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        c = int(count)
        samples += c
        frames = [_frame(f) for f in stack.split(";")]
        threads[frames[0]] += c
        own[frames[-1]] += c
        for f in set(frames[1:]):
            total[f] += c

    def share(counter: collections.Counter[str]) -> list[list[Any]]:
        return [[k, round(v / max(samples, 1), 3)] for k, v in counter.most_common(n)]

    return {
        "samples": samples,
        "threads": share(threads),
        "top_own": share(own),
        "top_total": share(total),
    }


# ----------------------------------------------------------------------------- one run
async def one_run(
    args: argparse.Namespace,
    gloves: int,
    name: str,
    python: str | None,
    env: dict[str, str],
    work: Path,
) -> dict[str, Any]:
    tag = f"{name}-{gloves}-{int(time.time())}"
    data = work / f"store-{tag}"
    server = TactusServer(data, work / f"server-{tag}.log", env, python)
    pid = server.proc.pid
    searchers = Searchers([server.base], args.searchers, args.search_pause, seed=gloves)
    out: dict[str, Any] = {"variant": name, "server_python": python or sys.executable}
    out.update(server_env=env, gloves=gloves, hz=args.hz)
    out["frames"] = "npy"
    try:
        print(f"[{tag}] warm-up {args.warmup_seconds}s", flush=True)
        await stream_gloves(
            [server.port],
            [f"g{g}" for g in range(gloves)],
            GloveStats(),
            hz=args.hz,
            window=WINDOW,
            clock=Barrier(gloves, args.warmup_seconds),
            drain_s=30,
        )
        idle: list[float] = []
        out["load1_before_idle"] = load1()
        await searchers.run(time.monotonic() + args.idle_seconds, idle)
        out["search_idle"] = summary(idle)

        print(f"[{tag}] load {args.seconds}s: {gloves} gloves x {args.hz} Hz", flush=True)
        stats = GloveStats()
        during: list[float] = []
        killed: list[float] = []
        prof: list[Profiler] = []
        cpu: dict[str, float] = {}
        out["load1_before_load"] = load1()

        async def others(clock: Barrier) -> None:
            await clock.go.wait()
            cpu.update(server=cpu_seconds(pid), client=cpu_seconds(os.getpid(), children=False))
            if args.profile:
                prof.append(Profiler(pid, args.seconds, work / f"{tag}.pyspy", args.rate))
            await searchers.run(clock.stop, during)
            cpu.update(
                server=cpu_seconds(pid) - cpu["server"],
                client=cpu_seconds(os.getpid(), children=False) - cpu["client"],
            )
            out["load1_after_load"] = load1()
            if prof:
                out["profile"] = await asyncio.to_thread(prof[0].finish)
            await asyncio.to_thread(server.kill9)
            killed.append(time.monotonic())

        clock = Barrier(gloves, args.seconds)
        sessions = [f"s{g}" for g in range(gloves)]
        streams = stream_until_killed(server.port, sessions, stats, args.hz, clock, killed)
        await asyncio.gather(streams, others(clock))
        acks, acked = acked_during(stats, clock)
        lost = len(acked - await asyncio.to_thread(stored_ids, data))
        out.update(
            seconds=args.seconds,
            windows_per_s_offered=round(gloves * args.hz / WINDOW, 1),
            windows_acked_per_s=round(len(acks) / args.seconds, 1),
            ack_latency=summary(acks),
            refused_503=stats.overloaded,
            error_frames=stats.errors,
            error_samples=stats.error_samples[:2],
            search_load=summary(during),
            search_errors=searchers.errors,
            acked_rows=len(acked),
            acked_rows_lost=lost,
            server_cpu_s=round(cpu["server"], 1),
            client_cpu_s=round(cpu["client"], 1),
            server_cpu_ms_per_window=round(cpu["server"] * 1e3 / max(len(acks), 1), 2),
        )
        if out["search_idle"]["p95_ms"] and out["search_load"]["p95_ms"]:
            ratio = out["search_load"]["p95_ms"] / out["search_idle"]["p95_ms"]
            out["search_p95_load_over_idle"] = round(ratio, 2)
    finally:
        server.kill9()
        if not args.keep_stores:
            shutil.rmtree(data, ignore_errors=True)
    keys = ("ack_latency", "refused_503", "search_p95_load_over_idle", "server_cpu_ms_per_window")
    print(f"[{tag}] " + json.dumps({k: out.get(k) for k in keys}), flush=True)
    return out


def parse_variant(spec: str) -> tuple[str, str | None, dict[str, str]]:
    """``NAME[@PYTHON][:KEY=VALUE,...]`` -> the name, the server's interpreter (another
    checkout's venv, for old-vs-new; None: this one) and its environment."""
    head, _, rest = spec.partition(":")
    name, _, python = head.partition("@")
    env = dict(kv.split("=", 1) for kv in rest.split(",") if kv)
    return name, python or None, env


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gloves", type=int, nargs="+", default=[64])
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=60.0)
    add_search_args(ap, idle_seconds=15.0)
    ap.add_argument("--variants", nargs="+", default=["default"])
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--profile", action="store_true", help="py-spy the server under load")
    ap.add_argument("--rate", type=int, default=50, help="py-spy samples per second")
    add_store_args(ap, "fleet_ii.json")
    args = ap.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="tactus-fleet-ii-"))
    work.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {**run_header("fleet_ii"), "targets": TARGETS, "runs": []}
    out = Path(args.out)
    for _ in range(args.rounds):
        for gloves in args.gloves:
            for spec in args.variants:
                name, python, env = parse_variant(spec)
                run = asyncio.run(one_run(args, gloves, name, python, env, work))
                result["runs"].append(run)
                result["load_average_now"] = os.getloadavg()
                out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
