"""A newcomer's first hour (issue 26), as CI runs it: a fresh copy of the checkout, `make run`,
then every ``bash`` and ``python`` block of the README's "Quickstart" sections, in order and
as written, then the page. Real uvicorn, real MiniLM, the shipped touch encoder.

* The copy holds the checkout's files (tracked and new, not ignored ones: no store, no
  runs), so ``./memory`` starts empty as on a fresh clone. The checkout's own ``.venv`` is
  linked in and ``make`` is told it is built (``-o .venv/.base``): nothing is installed.
* ``make run PORT=<free port>``; the README's ``localhost:8000`` / ``127.0.0.1:8000`` are
  rewritten to that port, nothing else. ``tactus`` is on PATH as after ``source
  .venv/bin/activate`` (the README's first step in a new terminal).
* A block followed by a ``prints`` block (```text) must print those lines in that order;
  ``...`` stands for anything. Every block must exit 0.
* The ROS 2 bag quickstart needs a bag: ``run1_bag`` is written first (real rosbags files,
  a note and a glove grasp), as the reader would have their own.
* The page: a search in a real Chromium shows hits with their match bar.

Also here: ``tactus serve`` opens its socket at once (``/live`` 200, ``/ready`` 503 naming
the step while the touch encoder loads), observed on a real server whose loading waits on a
gate file, so nothing depends on timing.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest

from benchmarks.serving import free_port, wait_ok
from tests.servers import stop_process

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
VENV = Path(sys.prefix)
STARTUP_S = 180
BLOCK_S = 300
FENCE = re.compile(r"^```(\w*)\n(.*?)^```\n", re.M | re.S)


@dataclass
class Block:
    section: str
    lang: str
    code: str
    prints: list[str] | None = None


def quickstart_blocks(text: str) -> list[Block]:
    """The bash/python blocks of the "## Quickstart..." sections, in order, each with the
    ```text block that follows it (after at most a line such as "prints")."""
    blocks: list[Block] = []
    sections = re.split(r"^## ", text, flags=re.M)
    for section in sections:
        title = section.splitlines()[0] if section else ""
        if not title.startswith("Quickstart"):
            continue
        last_end = None
        for m in FENCE.finditer(section):
            lang, code = m.group(1), m.group(2)
            between = section[last_end : m.start()] if last_end is not None else None
            if lang == "text" and blocks and between is not None and between.count("\n") <= 3:
                blocks[-1].prints = [ln for ln in code.splitlines() if ln.strip()]
            elif lang in ("bash", "python"):
                blocks.append(Block(title, lang, code))
            last_end = m.end()
    return blocks


def lines_in_order(expected: list[str], output: str) -> None:
    """Each expected line (``...``: anything) matches a line of ``output``, in order."""
    got = output.splitlines()
    i = 0
    for want in expected:
        pattern = re.compile(".*".join(re.escape(p) for p in want.split("...")))
        while i < len(got) and not pattern.fullmatch(got[i].rstrip()):
            i += 1
        assert i < len(got), f"the README says it prints {want!r}; it printed:\n{output}"
        i += 1


def fresh_copy(dest: Path) -> None:
    """The checkout's files as a fresh clone has them (tracked + new, not ignored)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    (dest / ".venv").symlink_to(VENV, target_is_directory=True)


def write_run1_bag(path: Path) -> None:
    """The reader's own recording: notes and a 3 s glove grasp (real ROS 2 bag files)."""
    from tests.recording_files import NS, glove, note, synthetic_grasp, write_bag

    msgs = [note("/notes", 1 * NS, "picked up the mug"), note("/notes", 4 * NS, "put it down")]
    msgs += glove("/glove/pressure", synthetic_grasp(90), start_ns=0)
    write_bag(path, msgs)


def shell_env(port: int) -> dict[str, str]:
    """As after ``source .venv/bin/activate``: the venv's bin first on PATH."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TACTUS_")}
    env["PATH"] = f"{VENV / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(VENV)
    env["OMP_NUM_THREADS"] = "1"
    return env


def run_block(block: Block, cwd: Path, port: int, env: dict[str, str]) -> str:
    code = re.sub(r"(localhost|127\.0\.0\.1):8000", rf"\1:{port}", block.code)
    if block.lang == "bash":
        cmd = ["bash", "-e", "-o", "pipefail", "-c", code]
    else:
        cmd = [str(VENV / "bin" / "python"), "-c", code]
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=BLOCK_S)
    out = done.stdout + done.stderr
    assert done.returncode == 0, f"README block in {block.section!r} failed:\n{code}\n---\n{out}"
    if block.prints:
        lines_in_order(block.prints, done.stdout)
    return out


def test_readme_quickstarts_run_as_written_on_a_fresh_copy(tmp_path: Path) -> None:
    clone = tmp_path / "tactus-memory"
    fresh_copy(clone)
    assert not (clone / "memory").exists()
    blocks = quickstart_blocks(README.read_text())
    assert [b.section for b in blocks if b.lang == "python"], "no Python quickstart"
    assert any("touch" in b.code and "npy" in b.code for b in blocks), "no touch over HTTP"
    assert any("websockets.connect" in b.code for b in blocks), "no glove client"
    port = free_port()
    log = tmp_path / "make-run.log"
    env = shell_env(port)
    make = ["make", "run", f"PORT={port}", "-o", ".venv/.base"]
    with log.open("ab") as fh:
        server = subprocess.Popen(
            make, cwd=clone, env=env, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True
        )
    base = f"http://127.0.0.1:{port}"
    try:
        if wait_ok(server, base + "/ready", STARTUP_S, interval=0.2) is None:
            pytest.fail(f"`make run` did not get ready in {STARTUP_S} s:\n{log.read_text()}")
        started = log.read_text()
        assert "pip" not in started.lower(), started  # nothing was installed
        assert f"memory browser: {base}/" in started and "ready: GET /ready" in started
        outputs: dict[str, list[str]] = {}
        timings: list[tuple[float, str]] = []
        for block in blocks:
            bag = clone / "run1_bag"
            if block.section.startswith("Quickstart: a ROS 2 bag") and not bag.exists():
                write_run1_bag(bag)
            t0 = time.monotonic()
            outputs.setdefault(block.section, []).append(run_block(block, clone, port, env))
            timings.append((round(time.monotonic() - t0, 1), block.code.splitlines()[0]))
        print("README blocks, seconds each:", timings)
        http = "\n".join(outputs["Quickstart: touch and notes over HTTP"])
        assert http.count('"count":1') == 3, http  # the note, the JSON window, the .npy one
        assert '"match":' in http and '"bar":' in http
        shell = "\n".join(outputs["Quickstart: the shell"])
        assert "1 occurrence of" in shell and "1 session" in shell and "<bool>" not in shell
        # the recording went into the store the server serves (it answered 404 before)
        assert (clone / "run1-served.rrd").stat().st_size > 1000
        assert (clone / "run1.rrd").stat().st_size > 1000
        assert '"deleted":' in shell  # the delete example
        sessions = {s["id"] for s in httpx.get(base + "/sessions").json()["sessions"]}
        assert "run1" in sessions and not {"s1", "s2"} & sessions, sessions  # both deleted
        page_search(base, tmp_path)
    finally:
        stop_process(server)
    assert (clone / "memory").is_dir()  # the one default store, in the checkout


def page_search(base: str, tmp_path: Path) -> None:
    """The page, as the newcomer opens it: a search lists hits, each with its match bar."""
    from tests.browser_util import launch, sync_playwright

    with sync_playwright() as pw:
        context = launch(pw, tmp_path / "chromium-profile")
        try:
            page = context.new_page()
            page.set_default_timeout(60_000)
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(base + "/")
            page.wait_for_selector("body[data-ready=true]")
            page.uncheck("#f-group")
            page.fill("#q", "holding a mug")
            page.keyboard.press("Enter")
            page.wait_for_selector("#results > li.hit")
            bars = page.eval_on_selector_all("#results .bar", "els => els.map(e => e.textContent)")
            hits = page.eval_on_selector_all("#results > li.hit", "els => els.length")
            assert bars and len(bars) == hits, (bars, hits)
            assert "clear the match bar" in page.text_content("#search-status")
            assert not errors, errors
        finally:
            context.close()


def test_serve_opens_its_socket_at_once_and_says_what_loads(tmp_path: Path) -> None:
    """``tactus serve`` (real uvicorn, real MiniLM): while the touch encoder loads, /live is
    200, /ready and /health are 503 naming the step, a search is 503 + Retry-After; then
    ready. The loading waits on a gate file here, so the window is observed, not raced."""
    gate = tmp_path / "gate"
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    hook = (
        "import os, time\n"
        "import tactus_memory.service.app as app\n"
        "load = app.register_default_senses\n"
        "def gated(*a, **k):\n"
        f"    end = time.monotonic() + {STARTUP_S}\n"
        f"    while not os.path.exists({str(gate)!r}) and time.monotonic() < end:\n"
        "        time.sleep(0.05)\n"
        "    return load(*a, **k)\n"
        "app.register_default_senses = gated\n"
        "from tactus_memory.cli import main\n"
        "main()\n"
    )
    cmd = [sys.executable, "-c", hook, "serve", "--port", str(port), "--data", str(tmp_path / "m")]
    log = tmp_path / "serve.log"
    with log.open("ab") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=shell_env(port))
    try:
        assert wait_ok(proc, base + "/live", STARTUP_S, interval=0.1) is not None, log.read_text()
        deadline = time.monotonic() + STARTUP_S
        while "[3/3] loading the touch encoder ..." not in log.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.1)
        r = httpx.get(base + "/ready")
        assert r.status_code == 503 and r.headers["retry-after"] == "1"
        assert "starting: [3/3] loading the touch encoder" in r.json()["detail"]
        assert httpx.get(base + "/health").status_code == 503
        r = httpx.get(base + "/search", params={"q": "a mug"})
        assert (
            r.status_code == 503 and "starting" in r.json()["detail"] and "retry-after" in r.headers
        )
        assert httpx.get(base + "/").status_code == 200  # the page loads and waits
        gate.touch()
        assert wait_ok(proc, base + "/ready", STARTUP_S, interval=0.1) is not None, log.read_text()
        assert httpx.get(base + "/health").json()["touch"] is True
        window = np.full((8, 32, 32), 512, np.int16)
        window[:, 10:22, 8:20] = 640
        r = httpx.post(f"{base}/sessions/s/touch", json={"frames": window.tolist(), "t": 1.0})
        assert r.status_code == 201, r.text
    finally:
        stop_process(proc)


def test_a_checkpoint_that_fails_to_load_after_the_socket_opened_exits_2(tmp_path: Path) -> None:
    """The touch encoder loads after the socket opens; a named checkpoint that cannot load
    still stops the command with its one-line reason and exit status 2."""
    bad = tmp_path / "broken.safetensors"
    bad.write_bytes(b"not a checkpoint")
    cmd = [sys.executable, "-c", "from tactus_memory.cli import main; main()", "serve"]
    cmd += ["--port", str(free_port()), "--data", str(tmp_path / "m")]
    cmd += ["--touch-checkpoint", str(bad)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=STARTUP_S, env=shell_env(0))
    assert done.returncode == 2, done.stderr[-2000:]
    last = [ln for ln in done.stderr.splitlines() if ln.startswith("tactus serve:")]
    assert len(last) == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
