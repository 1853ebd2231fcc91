"""What keys, tenants and the audit log cost (issue 25), on a real uvicorn over a local store
with the real MiniLM space:

* verifying a key: the first time a process sees it (scrypt, N=2^14, r=8) and after (cached);
* ``GET /sessions`` latency: an open store, the operator's token, a key (sequential requests);
* a tenant's first request (its memory is opened then) and the process RSS per open tenant;
* ``POST /sessions/{s}/text`` latency with the audit log on and off;
* ``GET /search`` latency with a key limited to sessions (``--sessions lab-``: the store ANDs
  ``starts_with(session, 'lab-')`` into the search) and with an unlimited key.

    python benchmarks/tenants.py                  # ~1-2 min on 2 cores
    python benchmarks/tenants.py --requests 100   # quicker

Writes JSON (default ``benchmarks/results/tenants.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
import psutil  # noqa: E402

from benchmarks.memory import pct  # noqa: E402
from benchmarks.serving import serve_app  # noqa: E402
from tactus_memory.memory.main import Memory  # noqa: E402
from tactus_memory.service.app import create_app  # noqa: E402
from tactus_memory.settings import Settings  # noqa: E402
from tactus_memory.spaces.minilm import MiniLMSpace  # noqa: E402
from tactus_memory.storage.keys import KeyStore  # noqa: E402


def _ms(xs: list[float]) -> dict[str, float]:
    return {"p50_ms": round(pct(xs, 50) * 1e3, 3), "p95_ms": round(pct(xs, 95) * 1e3, 3)}


def _latency(c: httpx.Client, n: int, method: str, url: str, **kw: Any) -> list[float]:
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        r = c.request(method, url.format(i=i), **kw)
        out.append(time.perf_counter() - t0)
        assert r.status_code < 300, r.text
    return out


def run(requests: int, tenants: int) -> dict[str, Any]:
    space = MiniLMSpace()
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        keys = KeyStore(tmp)
        made = [keys.create(f"t{i}", "write")[1] for i in range(5)]
        fresh = KeyStore(tmp)  # another process: nothing verified yet
        first = []
        for key in made:
            t0 = time.perf_counter()
            assert fresh.verify(key) is not None
            first.append(time.perf_counter() - t0)
        again = []
        for _ in range(2000):
            t0 = time.perf_counter()
            fresh.verify(made[0])
            again.append(time.perf_counter() - t0)
        out["verify_first"] = _ms(first)
        out["verify_cached"] = {"p50_us": round(pct(again, 50) * 1e6, 2)}

        for mode in ("open", "token", "key"):
            data = os.path.join(tmp, mode)
            memory = Memory.open(data, space)
            settings = Settings(token=None if mode == "open" else "op-token")
            if mode == "key":
                key = KeyStore(data).create("default", "write")[1]
                lab = KeyStore(data).create("default", "read", sessions="lab-")[1]
            if mode == "token":  # a tenant comes into being with its first key
                for i in range(tenants):
                    KeyStore(data).create(f"tenant-{i}", "read")
            headers = {
                "open": {},
                "token": {"Authorization": "Bearer op-token"},
                "key": {"Authorization": f"Bearer {key}" if mode == "key" else ""},
            }[mode]
            app = create_app(settings, memory=memory)
            with serve_app(app) as base, httpx.Client(base_url=base, timeout=60) as c:
                if mode == "key":
                    deadline = time.monotonic() + 30
                    while c.get("/sessions", headers=headers).status_code != 200:
                        assert time.monotonic() < deadline
                        time.sleep(0.1)
                c.get("/sessions", headers=headers)
                out[f"get_sessions_{mode}"] = _ms(
                    _latency(c, requests, "GET", "/sessions", headers=headers)
                )
                body = {"text": "a red mug on the shelf", "t": 1.0}
                writes: dict[str, list[float]] = {"audit_on": [], "audit_off": []}
                saved = app.state.tactus.audit
                for block in range(max(1, requests // 10)):  # interleaved: the same noise
                    for name in (
                        ("audit_on", "audit_off") if block % 2 else ("audit_off", "audit_on")
                    ):
                        app.state.tactus.audit = saved if name == "audit_on" else None
                        url = f"/sessions/{name}{block}-{{i}}/text"
                        writes[name] += _latency(c, 10, "POST", url, json=body, headers=headers)
                app.state.tactus.audit = saved
                writes = {k: _ms(v) for k, v in writes.items()}
                out[f"post_text_{mode}"] = writes
                if mode == "key":  # half the sessions under lab-, then interleaved searches
                    url = "/sessions/lab-{i}/text"
                    _latency(c, requests // 2, "POST", url, json=body, headers=headers)
                    limited = {"Authorization": f"Bearer {lab}"}
                    both = {"search_unlimited_key": headers, "search_limited_key": limited}
                    took: dict[str, list[float]] = {name: [] for name in both}
                    for block in range(max(1, requests // 10)):
                        for name in sorted(both, reverse=bool(block % 2)):
                            q = "/search?q=red+mug&k=10"
                            took[name] += _latency(c, 10, "GET", q, headers=both[name])
                    out |= {name: _ms(v) for name, v in took.items()}
                if mode == "token":
                    proc = psutil.Process()
                    rss0 = proc.memory_info().rss
                    opened = []
                    for i in range(tenants):
                        h = {**headers, "X-Tactus-Tenant": f"tenant-{i}"}
                        t0 = time.perf_counter()
                        assert c.get("/sessions", headers=h).status_code == 200
                        opened.append(time.perf_counter() - t0)
                    rss1 = proc.memory_info().rss
                    out["tenant_first_request"] = _ms(opened)
                    out["rss_per_tenant_mib"] = round((rss1 - rss0) / tenants / 2**20, 2)
                    out["tenants_opened"] = tenants
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=300)
    ap.add_argument("--tenants", type=int, default=20)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/tenants.json"))
    args = ap.parse_args()
    t0 = time.time()
    result = {
        "benchmark": "tenants",
        "requests": args.requests,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        **run(args.requests, args.tenants),
        "seconds": round(time.time() - t0, 1),
    }
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
