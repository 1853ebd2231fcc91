"""Fleet benchmark (issue 11): many gloves streaming for a long time, searches meanwhile,
and two replicas on one store. Real parts only: ``tactus serve`` subprocesses on 127.0.0.1
(free ports, a fresh store in a temp folder, the real MiniLM space and the shipped
TactusEncoder; the run stops if touch does not load).

(a) soak: ``--gloves`` (64) WebSocket gloves at ``--hz`` (30) stream raw ``.npy`` frames
    (window 8, stride 8) for ``--soak-seconds`` (600), ``--note-writers`` clients post a text
    note every ``--note-interval`` s, and ``--searchers`` (4) clients search back to back.
    Sampled every ``--sample-seconds``: the store folder's size on disk (``du``: allocated
    blocks), the live bytes (LanceDB ``Table.stats()['total_bytes']`` of the current version
    of every table), their ratio, the items table's version and rows. Reported: glove ack
    latency p50/p95/p99 (last frame of a window sent -> its ``stored`` ack, i.e. after the
    commit), note ack latency, errors, search p50/p95 idle (after a ``--warmup-seconds``
    fill, before the soak, no writes) vs during the soak vs idle after it. At the end of the
    soak the server is SIGKILLed while the gloves are still streaming, and every
    acknowledged row is looked up in the store: ``acked_rows_lost``.
(b) scales: the same at ``--scales`` gloves (8 256) for ``--scale-seconds`` (120) each.
(c) replicas: two servers on one store (each started with ``--replica-env``, default
    ``TACTUS_READ_CONSISTENCY=1``: the read-consistency setting of the store half of issue
    11). Visibility lag: a note acknowledged by one replica, polled on the other
    (``GET /sessions/{id}``) until it shows (null when not within ``--lag-timeout``). Then
    gloves and notes on both replicas; one is SIGKILLed halfway; acknowledged rows lost.
    Once per ``--replica-stores`` kind: ``local`` (a temp folder; JSON key ``replicas``) and
    ``s3`` (``s3://tactus-fleet/fleet`` on moto's S3 server, started here on a free port of
    127.0.0.1, the AWS_* variables passed to both servers; JSON key ``replicas_s3``).

    nohup nice .venv/bin/python benchmarks/fleet.py --soak-seconds 600 &      # full (lead)
    .venv/bin/python benchmarks/fleet.py --parts soak --soak-seconds 90       # quick check

Writes ``benchmarks/results/fleet.json`` (``--out``). The client runs on the same 2 cores as
the server (64 gloves at 30 Hz are ~2,000 WebSocket messages/s), so figures include that load.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from load import (
    Barrier,
    GloveStats,
    pct,
    queries,
    run_header,
    stream_gloves,
)
from serving import free_port, kill_process, start_serve, stop_process, wait_ok

ROOT = Path(__file__).resolve().parents[1]
K = 10
WINDOW = 8  # frames per window = stride (the shipped encoder's window)
STARTUP_S = 300
TARGETS = {
    "ack_p99_ms_64_gloves": 250.0,
    "errors": 0,
    "acked_rows_lost": 0,
    "search_p95_during_over_idle": 3.0,
    "disk_over_live": 2.0,
    "replica_visibility_s": 2.0,
}
S3_BUCKET = "tactus-fleet"  # on moto's server, started by (c) for --replica-stores s3


def summary(xs: list[float]) -> dict[str, float | int | None]:
    if not xs:
        return {"n": 0, "p50_ms": None, "p95_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "n": len(xs),
        "p50_ms": round(pct(xs, 50) * 1e3, 1),
        "p95_ms": round(pct(xs, 95) * 1e3, 1),
        "p99_ms": round(pct(xs, 99) * 1e3, 1),
        "max_ms": round(max(xs) * 1e3, 1),
    }


# ----------------------------------------------------------------------------- servers
class TactusServer:
    """``tactus serve`` in a subprocess on a free port of 127.0.0.1."""

    def __init__(
        self, data: Path | str, log: Path, env: dict[str, str], python: str | None = None
    ) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.proc = start_serve(self.port, data, log, env=env, python=python)
        r = wait_ok(self.proc, self.base + "/health", STARTUP_S)
        if r is None and self.proc.poll() is not None:
            raise SystemExit(f"server died:\n{log.read_text()[-3000:]}")
        if r is None:
            self.kill9()
            raise SystemExit(f"server did not start in {STARTUP_S}s")
        self.health = r.json()
        if not self.health.get("touch"):
            self.stop()
            raise SystemExit(f"touch did not load: {self.health.get('touch_unavailable')}")

    def kill9(self) -> None:
        kill_process(self.proc)

    def stop(self) -> None:
        stop_process(self.proc, 60)


# ----------------------------------------------------------------------------- the store
def disk_bytes(path: Path) -> int:
    """Allocated bytes under ``path`` (what ``du`` counts)."""
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            with contextlib.suppress(FileNotFoundError):  # removed by cleanup meanwhile
                total += os.lstat(os.path.join(root, name)).st_blocks * 512
    return total


def store_sample(path: Path, tries: int = 5) -> dict[str, Any]:
    """One look at the store from outside the server (a reader of its own). Listing versions
    races the server's cleanup (a manifest deleted between the listing and its read): such a
    look is taken again."""
    for _ in range(tries - 1):
        try:
            return _store_sample(path)
        except RuntimeError as exc:  # lance "Not found: ..._versions/N.manifest"
            if "Not found" not in str(exc):
                raise
    return _store_sample(path)


def _store_sample(path: Path) -> dict[str, Any]:
    import lancedb

    db = lancedb.connect(str(path))
    res = db.list_tables()
    live = 0
    out: dict[str, Any] = {}
    for name in getattr(res, "tables", res):
        tbl = db.open_table(name)
        stats = tbl.stats()
        live += int(stats["total_bytes"])
        if name == "items":
            out["items_version"] = int(tbl.version)
            out["items_versions_kept"] = len(tbl.list_versions())
            out["rows"] = int(stats["num_rows"])
            out["fragments"] = int(stats["fragment_stats"]["num_fragments"])
    du = disk_bytes(path)
    out.update(disk_bytes=du, live_bytes=live, disk_over_live=round(du / max(live, 1), 2))
    return out


def stored_ids(path: Path | str, options: dict[str, str] | None = None) -> set[str]:
    import lancedb

    tbl = lancedb.connect(str(path), storage_options=options).open_table("items")
    return set(tbl.to_lance().to_table(columns=["id"]).column("id").to_pylist())


# ----------------------------------------------------------------------------- clients
class Searchers:
    """``n`` clients searching back to back (unique queries: no cache answers them)."""

    def __init__(self, bases: list[str], n: int, pause: float, seed: int) -> None:
        self.bases = bases
        self.n = n
        self.pause = pause
        self.qs = queries(100_000, seed=seed)
        self.next_q = 0
        self.errors = 0
        self.error_samples: list[str] = []

    async def run(self, until: float, out: list[float]) -> None:
        await asyncio.gather(*(self._one(i, until, out) for i in range(self.n)))

    async def _one(self, i: int, until: float, out: list[float]) -> None:
        import httpx

        base = self.bases[i % len(self.bases)]
        async with httpx.AsyncClient(base_url=base, timeout=120) as c:
            while time.monotonic() < until:
                q = self.qs[self.next_q]
                self.next_q += 1
                t0 = time.perf_counter()
                try:
                    r = await c.get("/search", params={"q": q, "k": K})
                    ok = r.status_code == 200
                except httpx.TransportError as exc:
                    ok, r = False, exc
                if ok:
                    out.append(time.perf_counter() - t0)
                else:
                    self.errors += 1
                    if len(self.error_samples) < 3:
                        self.error_samples.append(str(getattr(r, "text", r))[:200])
                    await asyncio.sleep(0.5)
                await asyncio.sleep(self.pause)


class Notes:
    """Text-note writers: each posts a note every ``interval`` s; keeps acked ids."""

    def __init__(self, bases: list[str], n: int, interval: float, tag: str) -> None:
        self.bases = bases
        self.n = n
        self.interval = interval
        self.tag = tag
        self.lag: list[float] = []
        self.acked: list[str] = []
        self.errors = 0
        self.overloaded = 0
        self.error_samples: list[str] = []

    async def run(self, until: float) -> None:
        await asyncio.gather(*(self._one(i, until) for i in range(self.n)))

    async def _one(self, i: int, until: float) -> None:
        import httpx

        base = self.bases[i % len(self.bases)]
        session = f"notes-{self.tag}-{i}"
        async with httpx.AsyncClient(base_url=base, timeout=120) as c:
            j = 0
            while time.monotonic() < until:
                body = {"text": f"operator note {j} from writer {i}: the grip slipped", "t": j}
                t0 = time.perf_counter()
                try:
                    r = await c.post(f"/sessions/{session}/text", json=body)
                except httpx.TransportError:
                    return  # the server is gone (killed on purpose)
                if r.status_code == 201:
                    self.lag.append(time.perf_counter() - t0)
                    self.acked.extend(r.json()["ids"])
                else:
                    self.errors += 1
                    self.overloaded += r.status_code == 503
                    if len(self.error_samples) < 3:
                        self.error_samples.append(f"{r.status_code} {r.text[:200]}")
                j += 1
                await asyncio.sleep(self.interval)


async def stream_fleet(
    ports: list[int],
    gloves: int,
    hz: float,
    clock: Barrier,
    stats: GloveStats,
    tag: str,
    *,
    drain_s: float,
) -> None:
    """``gloves`` gloves spread over the servers' ``ports``, streaming from the moment
    ``clock`` has all its parties (the gloves, plus whoever else waits on it) until its stop."""
    sessions = [f"glove-{tag}-{g}" for g in range(gloves)]
    await stream_gloves(
        ports, sessions, stats, hz=hz, window=WINDOW, clock=clock, drain_s=drain_s, keep_ids=True
    )


def stream_until_killed(
    port: int, sessions: list[str], stats: GloveStats, hz: float, clock: Barrier, killed: list
) -> Any:
    """The gloves stream from ``clock``'s start until the server is killed (``killed`` gets
    an entry), then the connections drop; acknowledged ids are kept."""
    return stream_gloves(
        [port],
        sessions,
        stats,
        hz=hz,
        window=WINDOW,
        clock=clock,
        stop_at=lambda: clock.stop + 3600 if not killed else 0.0,
        drain_s=0,
        keep_ids=True,
    )


def acked_during(stats: GloveStats, clock: Barrier) -> tuple[list[float], set[str]]:
    """The ack latencies of the windows acknowledged before ``clock``'s stop, and every
    acknowledged id."""
    lags = [lag for at, lag in stats.lag_at if at <= clock.stop]
    return lags, {i for ids in stats.acked.values() for i in ids}


# ----------------------------------------------------------------------------- (a), (b)
async def soak_run(
    args: argparse.Namespace, gloves: int, seconds: float, work: Path, tag: str
) -> dict[str, Any]:
    data = work / f"store-{tag}"
    log = work / f"server-{tag}.log"
    env = dict(kv.split("=", 1) for kv in args.server_env)
    server = TactusServer(data, log, env)
    port = server.port
    searchers = Searchers([server.base], args.searchers, args.search_pause, seed=gloves)
    result: dict[str, Any] = {
        "gloves": gloves,
        "hz": args.hz,
        "window": WINDOW,
        "seconds": seconds,
        "note_writers": args.note_writers,
        "note_interval_s": args.note_interval,
        "searchers": args.searchers,
        "touch_encoder": server.health.get("touch"),
        "server_env": env,
    }
    try:
        # Warm-up fill (not measured): every sense has rows, indexes/caches are warm.
        print(f"[{tag}] warm-up {args.warmup_seconds}s", flush=True)
        warm = GloveStats()
        notes_warm = Notes([server.base], args.note_writers, args.note_interval, tag)
        until = time.monotonic() + args.warmup_seconds + 5
        await asyncio.gather(
            stream_fleet(
                [port], gloves, args.hz, Barrier(gloves, args.warmup_seconds), warm, tag, drain_s=30
            ),
            notes_warm.run(until),
        )
        idle: list[float] = []
        print(f"[{tag}] idle search {args.idle_seconds}s", flush=True)
        await searchers.run(time.monotonic() + args.idle_seconds, idle)
        result["search_idle_before"] = summary(idle)
        result["after_warmup"] = await asyncio.to_thread(store_sample, data)

        print(f"[{tag}] soak {seconds}s: {gloves} gloves x {args.hz} Hz", flush=True)
        stats = GloveStats()
        notes = Notes([server.base], args.note_writers, args.note_interval, tag)
        during: list[float] = []
        samples: list[dict[str, Any]] = []
        killed_at: list[float] = []

        async def sampler(clock: Barrier) -> None:
            await clock.go.wait()
            while time.monotonic() < clock.stop:
                s = await asyncio.to_thread(store_sample, data)
                s["t_s"] = round(time.monotonic() - clock.start, 1)
                samples.append(s)
                print(f"[{tag}] {json.dumps(s)}", flush=True)
                await asyncio.sleep(args.sample_seconds)

        async def others(clock: Barrier) -> None:
            await clock.go.wait()
            await asyncio.gather(
                searchers.run(clock.stop, during), notes.run(clock.stop), sampler(clock)
            )
            # The soak is over: SIGKILL the server while the gloves are still streaming.
            await asyncio.to_thread(server.kill9)
            killed_at.append(time.monotonic())

        clock = Barrier(gloves, seconds)
        sessions = [f"glove-{tag}-{g}" for g in range(gloves)]
        streams = stream_until_killed(port, sessions, stats, args.hz, clock, killed_at)
        await asyncio.gather(streams, others(clock))
        ack_during, acked = acked_during(stats, clock)
        acked |= set(notes.acked)
        stored = await asyncio.to_thread(stored_ids, data)
        final = await asyncio.to_thread(store_sample, data)
        result.update(
            windows_sent=stats.sent_frames // WINDOW,
            windows_acked=stats.stored,
            windows_acked_per_s=round(len(ack_during) / seconds, 1),
            windows_per_s_target=round(gloves * args.hz / WINDOW, 1),
            ack_latency=summary(ack_during),
            ack_latency_p99_per_minute_ms=_per_minute(stats.lag_at, clock.start, clock.stop),
            note_ack_latency=summary(notes.lag),
            notes_acked=len(notes.acked),
            errors={
                "glove_error_frames": stats.errors,
                "glove_overloaded_503": stats.overloaded,
                "glove_error_samples": stats.error_samples,
                "note_errors": notes.errors,
                "note_overloaded_503": notes.overloaded,
                "note_error_samples": notes.error_samples,
                "search_errors": searchers.errors,
                "search_error_samples": searchers.error_samples,
                "total": stats.errors + notes.errors + searchers.errors,
            },
            search_during=summary(during),
            samples=samples,
            disk_over_live_max=max((s["disk_over_live"] for s in samples), default=None),
            disk_over_live_last=samples[-1]["disk_over_live"] if samples else None,
            after_kill9=final,
            acked_rows=len(acked),
            acked_rows_lost=len(acked - stored),
        )
        # Idle search again on the full store (restart after the kill).
        server = TactusServer(data, log, env)
        idle_after: list[float] = []
        await searchers_for(server, args, gloves).run(
            time.monotonic() + args.idle_seconds, idle_after
        )
        result["search_idle_after"] = summary(idle_after)
        base_p95 = result["search_idle_before"]["p95_ms"]
        during_p95 = result["search_during"]["p95_ms"]
        if base_p95 and during_p95:
            result["search_p95_during_over_idle_before"] = round(during_p95 / base_p95, 2)
        if result["search_idle_after"]["p95_ms"] and during_p95:
            result["search_p95_during_over_idle_after"] = round(
                during_p95 / result["search_idle_after"]["p95_ms"], 2
            )
    finally:
        server.stop()
        if not args.keep_stores:
            shutil.rmtree(data, ignore_errors=True)
    return result


def searchers_for(server: TactusServer, args: argparse.Namespace, seed: int) -> Searchers:
    return Searchers([server.base], args.searchers, args.search_pause, seed=seed + 1)


def _per_minute(lag_at: list[tuple[float, float]], start: float, stop: float) -> list[float]:
    """Ack latency p99 (ms) per minute of the soak: does it drift as the store grows?"""
    out = []
    t = start
    while t < stop:
        xs = [lag for at, lag in lag_at if t <= at < min(t + 60, stop)]
        if xs:
            out.append(round(pct(xs, 99) * 1e3, 1))
        t += 60
    return out


# ----------------------------------------------------------------------------- (c)
def replicas_part(args: argparse.Namespace, work: Path, kind: str) -> dict[str, Any]:
    """(c) on one store kind: ``local`` (a temp folder) or ``s3`` (moto's server)."""
    if kind == "local":
        return asyncio.run(replicas_run(args, work, work / "store-replicas", {}, None))
    from s3local import moto_s3, storage_options

    with moto_s3(S3_BUCKET) as aws:
        uri = f"s3://{S3_BUCKET}/fleet"
        return asyncio.run(replicas_run(args, work, uri, aws, storage_options(aws)))


async def replicas_run(
    args: argparse.Namespace,
    work: Path,
    data: Path | str,
    store_env: dict[str, str],
    options: dict[str, str] | None,
) -> dict[str, Any]:
    import httpx

    env = dict(kv.split("=", 1) for kv in args.replica_env)
    tag = "local" if isinstance(data, Path) else "s3"
    a = TactusServer(data, work / f"replica-{tag}-a.log", {**store_env, **env})
    b = TactusServer(data, work / f"replica-{tag}-b.log", {**store_env, **env})
    store = "local folder" if tag == "local" else f"{data} on moto's S3 server (127.0.0.1)"
    result: dict[str, Any] = {"store": store, "env": env}
    result["lag_timeout_s"] = args.lag_timeout
    try:
        lags: list[float | None] = []
        async with httpx.AsyncClient(timeout=60) as c:
            for i in range(args.lag_samples):
                src, dst = (a, b) if i % 2 == 0 else (b, a)
                session = f"lag-{i}"
                r = await c.post(f"{src.base}/sessions/{session}/text", json={"text": "hi", "t": i})
                r.raise_for_status()
                acked = time.monotonic()
                seen = None
                while time.monotonic() - acked < args.lag_timeout:
                    if (await c.get(f"{dst.base}/sessions/{session}")).status_code == 200:
                        seen = round(time.monotonic() - acked, 3)
                        break
                    await asyncio.sleep(0.02)
                lags.append(seen)
        seen_lags = [x for x in lags if x is not None]
        result["visibility_lag_s"] = lags
        result["visibility"] = {
            "samples": len(lags),
            "seen": len(seen_lags),
            "p50_s": round(float(np.median(seen_lags)), 3) if seen_lags else None,
            "max_s": max(seen_lags) if seen_lags else None,
        }
        # Both replicas ingest; A is SIGKILLed halfway; B goes on to the end.
        seconds = args.replica_seconds
        stats = GloveStats()
        notes = Notes([a.base, b.base], 2, args.note_interval, "replicas")
        killed: list[float] = []
        clock = Barrier(args.replica_gloves + 1, seconds)

        async def rest() -> None:
            await clock.ready()
            await asyncio.gather(notes.run(clock.stop), _kill_after(a, seconds / 2, killed))

        fleet = stream_fleet(
            [a.port, b.port], args.replica_gloves, args.hz, clock, stats, "rep", drain_s=60
        )
        await asyncio.gather(fleet, rest())
        b.stop()
        acked = {i for ids in stats.acked.values() for i in ids} | set(notes.acked)
        stored = await asyncio.to_thread(stored_ids, data, options)
        result.update(
            gloves=args.replica_gloves,
            seconds=seconds,
            killed_replica="a",
            windows_acked=stats.stored,
            notes_acked=len(notes.acked),
            glove_error_frames=stats.errors,
            note_errors=notes.errors,
            gloves_disconnected=stats.disconnects,
            acked_rows=len(acked),
            acked_rows_lost=len(acked - stored),
            ack_latency=summary(stats.lag),
        )
    finally:
        a.stop()
        b.stop()
        if isinstance(data, Path) and not args.keep_stores:
            shutil.rmtree(data, ignore_errors=True)
    return result


async def _kill_after(server: TactusServer, delay: float, killed: list[float]) -> None:
    await asyncio.sleep(delay)
    await asyncio.to_thread(server.kill9)
    killed.append(time.monotonic())


# ----------------------------------------------------------------------------- main
def add_search_args(ap: argparse.ArgumentParser, idle_seconds: float) -> None:
    """The warm-up and the searchers' options (this script's and ``fleet_ii.py``'s)."""
    ap.add_argument("--warmup-seconds", type=float, default=10.0)
    ap.add_argument("--idle-seconds", type=float, default=idle_seconds)
    ap.add_argument("--searchers", type=int, default=4)
    ap.add_argument("--search-pause", type=float, default=0.05)


def add_store_args(ap: argparse.ArgumentParser, out_name: str) -> None:
    """Where the stores and the result go."""
    ap.add_argument("--workdir", default=None, help="default: a fresh temp folder")
    ap.add_argument("--keep-stores", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / out_name))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", nargs="+", default=["soak", "scales", "replicas"])
    ap.add_argument("--gloves", type=int, default=64)
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--soak-seconds", type=float, default=600.0)
    ap.add_argument("--scales", type=int, nargs="*", default=[8, 256])
    ap.add_argument("--scale-seconds", type=float, default=120.0)
    add_search_args(ap, idle_seconds=20.0)
    ap.add_argument("--note-writers", type=int, default=2)
    ap.add_argument("--note-interval", type=float, default=1.0)
    ap.add_argument("--sample-seconds", type=float, default=10.0)
    ap.add_argument("--server-env", nargs="*", default=[], help="KEY=VALUE for (a), (b)")
    ap.add_argument("--replica-env", nargs="*", default=["TACTUS_READ_CONSISTENCY=1"])
    ap.add_argument("--replica-gloves", type=int, default=16)
    ap.add_argument("--replica-seconds", type=float, default=30.0)
    ap.add_argument(
        "--replica-stores",
        nargs="+",
        choices=["local", "s3"],
        default=["local", "s3"],
        help="(c) once per store kind; s3 = moto's S3 server started here",
    )
    ap.add_argument("--lag-samples", type=int, default=10)
    ap.add_argument("--lag-timeout", type=float, default=10.0)
    add_store_args(ap, "fleet.json")
    args = ap.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="tactus-fleet-"))
    work.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {
        **run_header("fleet"),
        "targets": TARGETS,
        "workdir": str(work),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:
        result["load_average_now"] = os.getloadavg()
        out.write_text(json.dumps(result, indent=2) + "\n")

    if "soak" in args.parts:
        result["soak"] = asyncio.run(soak_run(args, args.gloves, args.soak_seconds, work, "soak"))
        save()
    if "scales" in args.parts:
        result["scales"] = []
        for n in args.scales:
            run = asyncio.run(soak_run(args, n, args.scale_seconds, work, f"scale{n}"))
            result["scales"].append(run)
            save()
    if "replicas" in args.parts:
        for kind in args.replica_stores:  # local -> "replicas", s3 -> "replicas_s3"
            key = "replicas" if kind == "local" else f"replicas_{kind}"
            print(f"[replicas] {kind} store", flush=True)
            result[key] = replicas_part(args, work, kind)
            save()
    save()
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
