"""Load for the service benchmarks (``service.py``, ``fleet.py``): simulated gloves (WebSocket
clients that stream binary ``.npy`` frames, uint16 raw sensor units, at a fixed rate into
``/sessions/{session}/touch/stream`` and time each window's acknowledgement), unique
natural-language queries, and small helpers.

A window's ack latency is measured from the moment its last frame was sent to the moment
its ``stored`` message arrived (the server acks only after the LanceDB commit).
"""

from __future__ import annotations

import asyncio
import io
import json
import os
import platform
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ADJ = [
    "soft",
    "hard",
    "warm",
    "cold",
    "smooth",
    "rough",
    "heavy",
    "light",
    "wet",
    "dry",
    "squishy",
    "sharp",
    "round",
    "flat",
    "sticky",
    "slippery",
    "fragile",
    "solid",
]
NOUN = [
    "mug",
    "ball",
    "sponge",
    "spoon",
    "bottle",
    "cup",
    "towel",
    "brick",
    "plate",
    "toy",
    "glove",
    "box",
    "book",
    "can",
    "knife",
    "apple",
    "handle",
    "bag",
    "block",
    "pen",
]


def run_header(benchmark: str) -> dict[str, Any]:
    """The head of a benchmark's JSON result: its name, the machine, the command line and
    the load average at the start."""
    return {
        "benchmark": benchmark,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "load_average_at_start": os.getloadavg(),
    }


def pct(xs: list[float], p: float) -> float:
    return float(np.percentile(np.asarray(xs), p)) if xs else float("nan")


def queries(n: int, seed: int) -> list[str]:
    """n unique natural-language queries (unique so no cache can answer them)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        a, b = rng.choice(ADJ, 2, replace=False)
        out.append(f"something {a} and {b} like a {rng.choice(NOUN)} #{seed}-{i}")
    return out


def npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def raw_frames(n: int = 16, seed: int = 1) -> list[bytes]:
    """n distinct (32, 32) uint16 frames in the STAG glove's raw range (~500-700), as .npy."""
    rng = np.random.default_rng(seed)
    return [npy((500 + 200 * rng.random((32, 32))).astype(np.uint16)) for _ in range(n)]


@dataclass
class GloveStats:
    """What every glove of a run adds to (one event loop: no locks needed)."""

    sent_frames: int = 0
    stored: int = 0
    stored_during: int = 0
    errors: int = 0
    overloaded: int = 0  # error frames with status 503 (write queue full: pushed back)
    error_samples: list[dict[str, Any]] = field(default_factory=list)
    lag: list[float] = field(default_factory=list)
    #: (monotonic time of the ack, ack latency in s), for latency over time
    lag_at: list[tuple[float, float]] = field(default_factory=list)
    expected: int = 0
    late_windows: int = 0
    last_ack: float = 0.0
    #: session -> acknowledged item ids (when ``keep_ids``)
    acked: dict[str, list[str]] = field(default_factory=dict)
    disconnects: int = 0


async def stream_glove(
    url: str,
    session: str,
    stats: GloveStats,
    *,
    hz: float,
    window: int,
    frames: list[bytes],
    ready: Callable[[], Awaitable[None]],
    stop_at: Callable[[], float],
    offset_s: float = 0.0,
    drain_s: float = 60.0,
    keep_ids: bool = False,
) -> None:
    """One glove: connect, wait for ``ready()`` (every client connected), stream frames at
    ``hz`` until ``stop_at()``, then wait up to ``drain_s`` for the outstanding acks.

    ``url`` is the stream URL with its query (``window``/``stride``/``hz`` as wanted).
    A dropped connection (e.g. the server was killed) ends the glove quietly.
    """
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    sent_at: dict[int, float] = {}
    if keep_ids:
        stats.acked.setdefault(session, [])
    try:
        async with connect(url, max_size=2**22, open_timeout=120) as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
            await ready()

            async def receiver() -> None:
                async for raw in ws:
                    msg = json.loads(raw)
                    now = time.monotonic()
                    if msg["type"] == "stored":
                        stats.stored += 1
                        stats.last_ack = max(stats.last_ack, now)
                        if now <= stop_at():
                            stats.stored_during += 1
                        if keep_ids:
                            stats.acked[session].append(msg["id"])
                        t_sent = sent_at.pop(msg["seq"], None)
                        if t_sent is not None:
                            stats.lag.append(now - t_sent)
                            stats.lag_at.append((now, now - t_sent))
                    elif msg["type"] == "error":
                        stats.errors += 1
                        if msg.get("error", {}).get("status") == 503:
                            stats.overloaded += 1
                        for seq in msg.get("windows", []):
                            sent_at.pop(seq, None)
                        if len(stats.error_samples) < 5:
                            stats.error_samples.append(msg)

            recv_task = asyncio.create_task(receiver())
            await asyncio.sleep(offset_s)
            n = 0
            nxt = time.monotonic()
            try:
                while time.monotonic() < stop_at():
                    await ws.send(frames[n % len(frames)])
                    n += 1
                    stats.sent_frames += 1
                    if n % window == 0:
                        sent_at[n // window - 1] = time.monotonic()
                    nxt += 1 / hz
                    delay = nxt - time.monotonic()
                    if delay > 0:
                        await asyncio.sleep(delay)
                stats.expected += n // window
                deadline = time.monotonic() + drain_s
                while sent_at and time.monotonic() < deadline and not recv_task.done():
                    await asyncio.sleep(0.05)
                stats.late_windows += len(sent_at)
                await ws.close()
            finally:
                recv_task.cancel()
    except (ConnectionClosed, OSError):
        stats.disconnects += 1


class Barrier:
    """``ready()`` returns once ``parties`` callers arrived; the run's clock starts then."""

    def __init__(self, parties: int, seconds: float) -> None:
        self.parties = parties
        self.seconds = seconds
        self.arrived = 0
        self.go = asyncio.Event()
        self.start = float("inf")
        self.stop = float("inf")

    async def ready(self) -> None:
        self.arrived += 1
        if self.arrived == self.parties:
            self.start = time.monotonic()
            self.stop = self.start + self.seconds
            self.go.set()
        await self.go.wait()

    def stop_at(self) -> float:
        return self.stop


def glove_url(port: int, session: str, hz: float, window: int) -> str:
    """A glove's stream: windows of ``window`` frames, no overlap, times from 0."""
    return (
        f"ws://127.0.0.1:{port}/sessions/{session}/touch/stream"
        f"?window={window}&stride={window}&hz={hz}&t0=0"
    )


async def stream_gloves(
    ports: list[int],
    sessions: list[str],
    stats: GloveStats,
    *,
    hz: float,
    window: int,
    clock: Barrier,
    stop_at: Callable[[], float] | None = None,
    **kw: Any,
) -> None:
    """One glove per session, spread over the servers' ``ports`` and over one frame period,
    streaming from the moment ``clock`` has all its parties until its stop (or ``stop_at``;
    ``kw`` go to :func:`stream_glove`)."""
    frames = raw_frames()
    await asyncio.gather(
        *(
            stream_glove(
                glove_url(ports[g % len(ports)], session, hz, window),
                session,
                stats,
                hz=hz,
                window=window,
                frames=frames,
                ready=clock.ready,
                stop_at=stop_at or clock.stop_at,
                offset_s=g / len(sessions) / hz,
                **kw,
            )
            for g, session in enumerate(sessions)
        )
    )
