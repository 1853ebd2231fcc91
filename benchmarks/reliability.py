"""Reliability: N kill -9 cycles of a real ``tactus serve`` under concurrent writers.

Each cycle starts ``tactus serve`` in a subprocess (uvicorn on 127.0.0.1, a free port, one
temporary LanceDB store kept across cycles, the real MiniLM space, the shipped touch encoder
unless ``--no-touch``), waits for ``/ready``, then runs concurrent writers until
``--acks`` writes are acknowledged (or ``--seconds`` pass) and SIGKILLs the server while they
are still writing:

* ``--http`` HTTP writers: ``POST /sessions/{s}/text`` with a unique text per request
  (every other request with an explicit id, re-sent once after the crash if it was in flight:
  the idempotent-retry path);
* ``--ws`` WebSocket writers: ``/sessions/{s}/touch/stream`` with binary ``.npy`` batches of
  raw (8, 32, 32) frames; every ``stored`` message is an acknowledged window.

After the last cycle the server is started once more and every session is read back through
``/sessions/{s}/timeline``. Reported (JSON, ``benchmarks/results/reliability.json``):
acknowledged writes, acknowledged-but-lost, duplicates (a text, an explicit id or a window
start stored twice), failed restarts (no ``/ready`` within ``--startup-s``), per-cycle
figures and restart times.

    python benchmarks/reliability.py --cycles 3 --acks 100          # quick (dev)
    nohup python benchmarks/reliability.py --cycles 20 --acks 300 &  # the issue's run
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import subprocess
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from load import npy
from serving import free_port, kill_process, start_serve, wait_ok

ROOT = Path(__file__).resolve().parents[1]
WINDOW = 8  # frames per touch window (the stream default, Settings.window)


class Server:
    """``tactus serve`` in a subprocess; ``start`` returns seconds to /ready or None."""

    def __init__(self, data: Path, log: Path, touch: bool, token: str) -> None:
        self.data, self.log, self.touch, self.token = data, log, touch, token
        self.proc: subprocess.Popen | None = None
        self.port = 0

    def start(self, startup_s: float) -> float | None:
        self.port = free_port()
        token = ["--token", self.token, *([] if self.touch else ["--no-touch"])]
        t0 = time.monotonic()
        self.proc = start_serve(
            self.port, self.data, self.log, *token, env={"OMP_NUM_THREADS": "1"}
        )
        base = f"http://127.0.0.1:{self.port}"
        if wait_ok(self.proc, base + "/ready", startup_s, interval=0.2) is not None:
            return time.monotonic() - t0
        self.kill()
        return None

    def kill(self) -> None:
        kill_process(self.proc)


class Ledger:
    """What the clients were told: acknowledged texts/ids/windows, per session."""

    def __init__(self) -> None:
        self.texts: dict[str, str] = {}  # text -> session (acknowledged)
        self.ids: dict[str, str] = {}  # item id -> session (acknowledged)
        self.in_flight: list[dict[str, Any]] = []  # explicit-id requests cut by the kill
        self.windows: dict[str, set[str]] = {}  # session -> acknowledged window ids
        self.errors: Counter[str] = Counter()

    @property
    def acked(self) -> int:
        return len(self.ids) + sum(len(v) for v in self.windows.values())


async def run_cycle(
    server: Server, ledger: Ledger, cycle: int, args: argparse.Namespace
) -> dict[str, Any]:
    import httpx
    from websockets.asyncio.client import connect

    base = f"http://127.0.0.1:{server.port}"
    auth = {"Authorization": f"Bearer {server.token}"}
    acked_before = ledger.acked
    done = asyncio.Event()
    stop_at = time.monotonic() + args.seconds

    def enough() -> None:
        if ledger.acked - acked_before >= args.acks:
            done.set()

    async def http_writer(w: int) -> None:
        session = f"h{w}c{cycle}"
        async with httpx.AsyncClient(base_url=base, headers=auth, timeout=30) as c:
            i = 0
            while not done.is_set():
                text = f"note cycle {cycle} writer {w} number {i}"
                body: dict[str, Any] = {"text": text, "t": float(i)}
                if i % 2:
                    body["id"] = f"x{cycle}-{w}-{i}"
                try:
                    r = await c.post(f"/sessions/{session}/text", json=body)
                except httpx.HTTPError as exc:
                    if "id" in body:
                        ledger.in_flight.append({"session": session, **body})
                    ledger.errors[f"http:{type(exc).__name__}"] += 1
                    return
                if r.status_code != 201:
                    ledger.errors[f"http:{r.status_code}"] += 1
                    await asyncio.sleep(0.05)
                    continue
                (item_id,) = r.json()["ids"]
                ledger.ids[item_id] = session
                ledger.texts[text] = session
                i += 1
                enough()

    async def ws_writer(w: int) -> None:
        session = f"w{w}c{cycle}"
        url = (
            f"ws://127.0.0.1:{server.port}/sessions/{session}/touch/stream"
            f"?window={WINDOW}&stride={WINDOW}&hz=30&t0=0&token={server.token}"
        )
        rng = np.random.default_rng(cycle * 100 + w)
        acked = ledger.windows.setdefault(session, set())
        try:
            async with connect(url, max_size=2**22, open_timeout=60) as ws:
                if json.loads(await ws.recv())["type"] != "ready":
                    ledger.errors["ws:not-ready"] += 1
                    return

                async def receive() -> None:
                    async for raw in ws:
                        msg = json.loads(raw)
                        if msg["type"] == "stored":
                            acked.add(msg["id"])
                            enough()
                        elif msg["type"] == "error":
                            ledger.errors["ws:error-message"] += 1

                receiver = asyncio.create_task(receive())
                while not done.is_set() and not receiver.done():
                    frames = (500 + 200 * rng.random((WINDOW * 4, 32, 32))).astype(np.uint16)
                    await ws.send(npy(frames))
                    await asyncio.sleep(0.1)
                await receiver
        except Exception as exc:  # noqa: BLE001  (the kill cuts every connection)
            ledger.errors[f"ws:{type(exc).__name__}"] += 1

    async def killer() -> None:
        while not done.is_set() and time.monotonic() < stop_at:
            await asyncio.sleep(0.05)
        server.kill()  # SIGKILL while the writers are still writing
        done.set()

    t0 = time.monotonic()
    await asyncio.gather(
        killer(),
        *(http_writer(w) for w in range(args.http)),
        *(ws_writer(w) for w in range(args.ws if server.touch else 0)),
    )
    return {
        "cycle": cycle,
        "acked": ledger.acked - acked_before,
        "seconds": round(time.monotonic() - t0, 2),
    }


def retry_in_flight(base: str, token: str, ledger: Ledger) -> dict[str, int]:
    """Re-send the explicit-id writes cut by a kill: must be a 201 upsert, never a copy."""
    import httpx

    out = Counter()
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}) as c:
        for req in ledger.in_flight:
            body = {k: v for k, v in req.items() if k != "session"}
            r = c.post(f"/sessions/{req['session']}/text", json=body, timeout=30)
            out[str(r.status_code)] += 1
            if r.status_code == 201:
                ledger.ids[body["id"]] = req["session"]
                ledger.texts[body["text"]] = req["session"]
    ledger.in_flight.clear()
    return dict(out)


def verify(base: str, token: str, ledger: Ledger) -> dict[str, Any]:
    import httpx

    auth = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=base, headers=auth, timeout=120) as c:
        sessions = [s["id"] for s in c.get("/sessions").json()["sessions"]]
        rows: list[dict[str, Any]] = []
        for s in sessions:
            r = c.get(f"/sessions/{s}/timeline", params={"limit": 100_000})
            r.raise_for_status()
            rows += r.json()["items"]
    ids = Counter(r["id"] for r in rows)
    texts = Counter(r["text"] for r in rows if r["sense"] == "text")
    starts = Counter((r["session"], r["source"], r["t"]) for r in rows if r["sense"] == "touch")
    stored = {r["id"]: r["session"] for r in rows}
    lost_ids = [i for i, s in ledger.ids.items() if stored.get(i) != s]
    lost_windows = [i for s, ids_ in ledger.windows.items() for i in ids_ if stored.get(i) != s]
    stored_texts = set(texts)
    lost_texts = [t for t in ledger.texts if t not in stored_texts]
    return {
        "rows_stored": len(rows),
        "sessions": len(sessions),
        "acked_lost": len(set(lost_ids) | set(lost_windows)),
        "acked_texts_lost": len(lost_texts),
        "lost_examples": (lost_ids + lost_windows)[:5],
        "duplicate_ids": sum(n - 1 for n in ids.values() if n > 1),
        "duplicate_texts": sum(n - 1 for n in texts.values() if n > 1),
        "duplicate_windows": sum(n - 1 for n in starts.values() if n > 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--acks", type=int, default=300, help="acknowledged writes per cycle")
    ap.add_argument("--seconds", type=float, default=120, help="longest a cycle writes")
    ap.add_argument("--http", type=int, default=4, help="concurrent HTTP writers")
    ap.add_argument("--ws", type=int, default=2, help="concurrent WebSocket touch writers")
    ap.add_argument("--no-touch", action="store_true", help="no touch encoder, no WS writers")
    ap.add_argument("--startup-s", type=float, default=240)
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/reliability.json")
    args = ap.parse_args()

    work = args.workdir or Path(tempfile.mkdtemp(prefix="tactus-reliability-"))
    work.mkdir(parents=True, exist_ok=True)
    server = Server(
        work / "memory", work / "server.log", not args.no_touch, "rel-" + os.urandom(6).hex()
    )
    ledger = Ledger()
    cycles: list[dict[str, Any]] = []
    restarts: list[float] = []
    failed_restarts = 0
    retries: Counter[str] = Counter()
    t_start = time.time()
    for cycle in range(args.cycles):
        up = server.start(args.startup_s)
        if up is None:
            failed_restarts += 1
            print(f"cycle {cycle}: server did not become ready", flush=True)
            continue
        restarts.append(up)
        if ledger.in_flight:
            retries.update(retry_in_flight(f"http://127.0.0.1:{server.port}", server.token, ledger))
        stats = asyncio.run(run_cycle(server, ledger, cycle, args))
        stats["ready_s"] = round(up, 2)
        cycles.append(stats)
        print(json.dumps(stats), f"total acked {ledger.acked}", flush=True)
        partial = {"benchmark": "reliability", "partial": True, "cycles": cycles}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(partial, indent=2) + "\n")  # kept if the run is cut
    up = server.start(args.startup_s)
    if up is None:
        failed_restarts += 1
        result: dict[str, Any] = {"error": "the final restart failed; nothing verified"}
    else:
        restarts.append(up)
        base = f"http://127.0.0.1:{server.port}"
        if ledger.in_flight:
            retries.update(retry_in_flight(base, server.token, ledger))
        result = verify(base, server.token, ledger)
        server.kill()
    report = {
        "benchmark": "reliability",
        "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t_start)),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "config": {
            "cycles": args.cycles,
            "acks_per_cycle": args.acks,
            "http_writers": args.http,
            "ws_writers": 0 if args.no_touch else args.ws,
            "space": "minilm",
            "touch": not args.no_touch,
        },
        "kills": len(cycles),
        "acked_writes": ledger.acked,
        "acked_text_writes": len(ledger.ids),
        "acked_touch_windows": sum(len(v) for v in ledger.windows.values()),
        "failed_restarts": failed_restarts,
        "in_flight_retries": dict(retries),
        **result,
        "client_errors": dict(ledger.errors),
        "ready_s": {
            "mean": round(float(np.mean(restarts)), 2) if restarts else None,
            "max": round(float(np.max(restarts)), 2) if restarts else None,
        },
        "wall_s": round(time.time() - t_start, 1),
        "cycles": cycles,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps({k: v for k, v in report.items() if k != "cycles"}, indent=2))


if __name__ == "__main__":
    main()
