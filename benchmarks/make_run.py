"""A newcomer's ``make run``: from a fresh clone to the line ``ready: GET /ready answers 200``.

Clones the checkout's HEAD into a temporary folder and runs ``make run`` there with an empty
user cache (so the first start writes MiniLM's ONNX graph) on a free port, then records:

* ``ready_s``: seconds from ``make run`` to the ready line (venv, pip install, start, export);
* ``rss_mb``: the serving process's resident memory once ready (VmRSS, /proc);
* ``install_mb``: the size of the clone's ``.venv`` (and of its torch side, none expected);
* the machine's load average (1 min) before and at ready, and its core count.

    python benchmarks/make_run.py               # pip's cache as it is (warm after one run)
    python benchmarks/make_run.py --cold        # PIP_NO_CACHE_DIR=1: every wheel fetched again

Results go to ``benchmarks/results/make_run_{cold,warm}.json`` (one run appended per call).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from serving import free_port

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
READY_LINE = "ready: GET /ready answers 200"
#: the give-up point of one run (a run that never gets ready is recorded as such)
GIVE_UP_S = 1800
TORCH_SIDE = ("torch", "functorch", "torchgen", "sentence_transformers", "transformers", "nvidia")


def _du_mb(path: Path) -> float:
    out = subprocess.run(["du", "-sb", str(path)], capture_output=True, text=True, check=True)
    return round(int(out.stdout.split()[0]) / 1e6, 1)


def _rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    kb = int(re.search(r"VmRSS:\s+(\d+) kB", status).group(1))  # type: ignore[union-attr]
    return round(kb / 1024, 1)


def _server_pid(root_pid: int) -> int | None:
    """The ``tactus serve`` process under ``make`` (the one that loads the models)."""
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            ppid = int(re.search(r"PPid:\s+(\d+)", (proc / "status").read_text()).group(1))  # type: ignore[union-attr]
        except (OSError, AttributeError):
            continue
        if "tactus serve" in cmd and ppid == root_pid:
            return int(proc.name)
    return None


def run(cold: bool) -> dict[str, object]:
    tmp = Path(tempfile.mkdtemp(prefix="make-run-"))
    try:
        clone = tmp / "clone"
        subprocess.run(["git", "clone", "-q", "--local", str(ROOT), str(clone)], check=True)
        port = free_port()
        env = {
            **os.environ,
            "TACTUS_CACHE": str(tmp / "cache"),
            "PORT": str(port),
            "PIP_DISABLE_PIP_VERSION_CHECK": "1",
        }
        env.pop("VIRTUAL_ENV", None)
        if cold:
            env["PIP_NO_CACHE_DIR"] = "1"
        load_before = os.getloadavg()[0]
        t0 = time.monotonic()
        proc = subprocess.Popen(
            ["make", "run"],
            cwd=clone,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        lines: list[str] = []
        ready_s = None
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.rstrip())
            if READY_LINE in line:
                ready_s = round(time.monotonic() - t0, 1)
                break
            if time.monotonic() - t0 > GIVE_UP_S:
                break
        load_ready = os.getloadavg()[0]
        time.sleep(2)  # the first /ready probe's garbage settles
        pid = _server_pid(proc.pid)
        rss = _rss_mb(pid) if pid is not None and ready_s is not None else None
        venv = clone / ".venv"
        site = next(venv.glob("lib/python*/site-packages"))
        torch_side = [p.name for p in site.iterdir() if p.name.split("-")[0] in TORCH_SIDE]
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
        return {
            "cold": cold,
            "ready_s": ready_s,
            "rss_mb": rss,
            "install_mb": _du_mb(venv),
            "torch_side_installed": torch_side,
            "load_1min_before": round(load_before, 2),
            "load_1min_at_ready": round(load_ready, 2),
            "cores": os.cpu_count(),
            "python": sys.version.split()[0],
            "last_lines": lines[-6:],
            "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cold", action="store_true", help="no pip cache (PIP_NO_CACHE_DIR=1)")
    args = ap.parse_args()
    result = run(args.cold)
    print(json.dumps(result, indent=2))
    out = RESULTS / f"make_run_{'cold' if args.cold else 'warm'}.json"
    runs = json.loads(out.read_text())["runs"] if out.exists() else []
    out.write_text(json.dumps({"runs": [*runs, result]}, indent=2) + "\n")


if __name__ == "__main__":
    main()
