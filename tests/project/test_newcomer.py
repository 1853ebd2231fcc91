"""A newcomer's first hour, as CI runs it: a fresh copy of the checkout, an empty ``HOME``,
``make run``, then every ``bash`` and ``python`` block of the README's tour and of every page
of the docs site (``mkdocs.yml``'s nav, in its order: Getting started, every guide, the
reference and operations pages), as written (``--8<--`` includes of ``examples/`` resolved as
the docs build does; ``tests/helpers/doc_snippets.py``), then the page, then ruff and the
checkout tests in the same folder. Real uvicorn on 127.0.0.1, real MiniLM, the shipped touch
encoder. A block runs unless its page marks it, visibly, as needing what a fresh clone does
not have (the STAG files, a GPU, an S3 bucket, ...): ``tests/project/test_doc_snippets.py`` keeps
those
few and each with its reason.

* The copy holds the checkout's files (tracked and new, not ignored ones: no store, no
  runs), so ``./memory`` starts empty as on a fresh clone. The checkout's own ``.venv`` is
  linked in and ``make`` is told it is built (``-o .venv/.base``): nothing is installed.
* The block that is ``make run`` starts the server (``PORT=<free port>``); the docs'
  ``localhost:8000`` / ``127.0.0.1:8000`` are rewritten to that port, nothing else.
  ``tactus`` is on PATH as after ``source .venv/bin/activate`` (a block of its own).
* The blocks run as in ``make run``'s venv, which installs no PyTorch: torch,
  sentence-transformers and transformers cannot be imported there
  (:data:`benchmarks.serving.NO_TORCH`), so the models run on ONNX Runtime as a newcomer's
  do; a block that runs a command of the ``train`` extra (:data:`TRAIN_EXTRA`: PyTorch comes
  with ``make test``, as Getting started says) runs with the whole venv.
* ``curl`` fails on an HTTP error (``--fail-with-body``): a snippet answered 404 fails here.
* A block followed by a ``prints`` block (```text) must print those lines in that order;
  ``...`` stands for anything. Every block must exit 0.
* Anything a snippet needs (a recording, poses, arrays) is made by an earlier snippet or
  by a script in ``examples/``.
* The page: a search in a real Chromium shows hits with their match bar; ``/docs`` and
  ``/redoc`` render there with every request off the server refused (offline).

Also here: ``tactus serve`` opens its socket at once (``/live`` 200, ``/ready`` 503 naming
the step while the touch encoder loads), observed on a real server whose loading waits on a
gate file, so nothing depends on timing.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from benchmarks.serving import copy_checkout, free_port, wait_ok
from benchmarks.serving import without_torch as serving_without_torch
from tests.helpers.doc_snippets import Block, all_blocks, nav_pages
from tests.helpers.servers import STARTUP_S, stop_process

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)
BLOCK_S = 300
MAKE_RUN = re.compile(r"^make run(\s+#.*)?\n$")
CURL_FAILS = 'curl() { command curl --fail-with-body -sS "$@"; }\n'
#: guides none of whose blocks runs on a fresh clone (each marked: the STAG files, a GPU, the
#: Qwen3-VL weights); every other guide must run blocks
NO_RUNNABLE_BLOCK = ("docs/guides/images.md", "docs/guides/training.md")
#: the tests `make test` runs whose answer depends on the files at the checkout's top (the
#: lint config, the snippet marks): run again in the clone after the snippets, whose files
#: (./memory, recordings, runs/) land there. The docs build and the layer map read docs/ and
#: the package folders, which no snippet writes into; the suite's own run checks them
CHECKOUT_TESTS = ("test_lint_config.py", "test_doc_snippets.py")
#: blocks running a command of the ``train`` extra (PyTorch): they run with the whole venv
TRAIN_EXTRA = re.compile(r"^\s*tactus (adapt|export-onnx)\b", re.M)


def lines_in_order(expected: list[str], output: str) -> None:
    """Each expected line (``...``: anything) matches a line of ``output``, in order."""
    got = output.splitlines()
    i = 0
    for want in expected:
        pattern = re.compile(".*".join(re.escape(p) for p in want.split("...")))
        while i < len(got) and not pattern.fullmatch(got[i].rstrip()):
            i += 1
        assert i < len(got), f"the docs say it prints {want!r}; it printed:\n{output}"
        i += 1


def fresh_copy(dest: Path) -> None:
    """The checkout's files as a fresh clone has them (tracked + new, not ignored), in a git
    repository of their own."""
    copy_checkout(ROOT, dest)
    # a clone is a git repository: `git ls-files` answers there as in the checkout
    git = ["git", "-c", "user.name=newcomer", "-c", "user.email=newcomer@example.invalid"]
    for args in (["init", "-q"], ["add", "-A"], ["commit", "-q", "-m", "fresh clone"]):
        subprocess.run([*git, *args], cwd=dest, capture_output=True, check=True)
    (dest / ".venv").symlink_to(VENV, target_is_directory=True)


def shell_env(port: int, home: Path | None = None) -> dict[str, str]:
    """As after ``source .venv/bin/activate``: the venv's bin first on PATH (and an empty
    ``HOME`` of its own when given: nothing of the developer's user folder is used)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TACTUS_", "XDG_"))}
    env["PATH"] = f"{VENV / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(VENV)
    env["OMP_NUM_THREADS"] = "1"
    if home is not None:
        home.mkdir(exist_ok=True)
        env["HOME"] = str(home)
    return env


def without_torch(env: dict[str, str], folder: Path) -> dict[str, str]:
    """``env`` with what ``make run`` does not install (the ``train`` extra's side, as in
    tests/project/test_serve_without_torch.py) unimportable in every Python process
    (:func:`benchmarks.serving.without_torch`): the blocks' models then run on ONNX Runtime,
    as a newcomer's do (and ~3x cheaper: 7.8 against 22.4 CPU-seconds for the README's Python
    block on the loaded 2-core machine)."""
    return serving_without_torch(env, folder, VENV / "bin" / "tactus")


def run_block(block: Block, cwd: Path, port: int, env: dict[str, str]) -> str:
    code = re.sub(r"(localhost|127\.0\.0\.1):8000", rf"\1:{port}", block.code)
    if block.lang == "bash":
        cmd = ["bash", "-e", "-o", "pipefail", "-c", CURL_FAILS + code]
    else:
        cmd = [str(VENV / "bin" / "python"), "-c", code]
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=BLOCK_S)
    out = done.stdout + done.stderr
    where = f"{block.page} ({block.section!r})"
    assert done.returncode == 0, f"block of {where} failed:\n{code}\n---\n{out}"
    if block.prints:
        lines_in_order(block.prints, done.stdout)
    return out


def test_every_snippet_runs_as_written_on_a_fresh_copy(tmp_path: Path) -> None:
    clone = tmp_path / "tactus-memory"
    fresh_copy(clone)
    assert not (clone / "memory").exists()
    blocks = [b for b in all_blocks() if b.exempt is None]
    starts = [b for b in blocks if MAKE_RUN.match(b.code)]
    assert len(starts) == 1 and starts[0].page == "docs/getting-started.md", starts
    assert [b for b in blocks if b.page == "README.md"], "no tour in the README"
    pages = nav_pages()
    ran = {b.page for b in blocks}
    assert "docs/getting-started.md" in pages and "docs/reference/mcp.md" in pages
    guides = [p for p in pages if p.startswith("docs/guides/")]
    assert len(guides) >= 8 and set(guides) <= ran | set(NO_RUNNABLE_BLOCK), (guides, ran)
    assert any("websockets.connect" in b.code for b in blocks), "no glove client"
    assert any("make_recording.py" in b.code for b in blocks), "no recording"
    port = free_port()
    log = tmp_path / "make-run.log"
    home = tmp_path / "home"
    env = shell_env(port, home)
    make = ["make", "run", f"PORT={port}", "-o", ".venv/.base"]  # the block, on a free port
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
        # the light server: ONNX Runtime from the user's cache (MiniLM exported there on this
        # first start, the touch graph shipped), torch never loaded by the server
        onnx = home / ".cache" / "tactus" / "onnx"
        assert f"models run on:  ONNX Runtime ({onnx}/" in started, started
        assert "exporting MiniLM to ONNX once" in started, started
        (served,) = serving_processes(server.pid)
        maps = Path(f"/proc/{served}/maps").read_text()
        assert "onnxruntime" in maps and "libtorch" not in maps
        # the README's tour comes after `make run`: run the pages' blocks in that order
        order = [b for b in blocks if b.page != "README.md"]
        i = order.index(starts[0]) + 1
        order = [*order[:i], *[b for b in blocks if b.page == "README.md"], *order[i:]]
        outputs: dict[str, list[str]] = {}
        timings: list[tuple[float, str]] = []
        served = without_torch(env, tmp_path / "no-torch")  # as in make run's venv
        no_torch = "from tactus_memory.spaces.onnx_runtime import has_torch as h; assert not h()"
        subprocess.run([str(VENV / "bin" / "python"), "-c", no_torch], env=served, check=True)
        assert any(TRAIN_EXTRA.search(b.code) for b in order), "no train-extra block"
        for block in order:
            if block is starts[0]:
                continue  # the server above
            t0 = time.monotonic()
            out = run_block(block, clone, port, env if TRAIN_EXTRA.search(block.code) else served)
            outputs.setdefault(block.section, []).append(out)
            timings.append((round(time.monotonic() - t0, 1), block.code.splitlines()[0]))
        print("snippets, seconds each:", timings)
        http = "\n".join(outputs["Quickstart: touch and notes over HTTP"])
        assert http.count('"count":1') == 3, http  # the note, the JSON window, the .npy one
        assert '"match":' in http and '"bar":' in http
        shell = "\n".join(outputs["Quickstart: the shell"])
        assert "1 occurrence of" in shell and "<bool>" not in shell
        assert re.search(r"\b\d+ sessions?\b", shell), shell
        assert '"deleted":' in shell  # the delete example
        # the recording went into the store the server serves
        assert (clone / "run1-served.rrd").stat().st_size > 1000
        assert (clone / "run1.rrd").stat().st_size > 1000
        sessions = {s["id"] for s in httpx.get(base + "/sessions").json()["sessions"]}
        assert {"run1", "tour", "kitchen", "walk", "yard", "desk"} <= sessions, sessions
        assert not {"s1", "s2"} & sessions, sessions  # both deleted
        # examples/mcp_client.py ran as the MCP reference page's block, as written: each
        # request within its default --read-timeout, the Inspector's limit
        # (test_the_agent_example_grants_a_request_the_inspectors_limit)
        agent = "\n".join(outputs["An agent's calls, from Python"])
        assert agent.startswith("tools: ") and "where " in agent, agent
        agent_calls(clone, served)
        where = httpx.get(base + "/where", params={"q": "picked up the drill", "session": "yard"})
        assert where.json()["places"][0]["position"][0] == pytest.approx(6.0, abs=0.1), where.text
        page_search(base, tmp_path)
    finally:
        stop_process(server)
    assert (clone / "memory").is_dir()  # the one default store, in the checkout
    # `make test` in the same checkout after all that: its ruff (the store and what the
    # snippets left must not change what ruff sees; `make lint`'s mypy checks the package
    # alone, which no snippet writes into, and runs in the suite's own `make test`), and the
    # checkout's own checks
    for ruff in (["check", "."], ["format", "--check", "."]):
        done = subprocess.run(
            [str(VENV / "bin" / "ruff"), *ruff], cwd=clone, env=env, capture_output=True,
            text=True, timeout=300,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
    checks = [str(VENV / "bin" / "python"), "-m", "pytest", "-q", "-p", "no:cacheprovider"]
    checks += [f"tests/project/{name}" for name in CHECKOUT_TESTS]
    done = subprocess.run(checks, cwd=clone, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]


#: the MCP Inspector's CLI's read limit per request: what an agent's client grants a call
AGENT_TIMEOUT_S = 30
#: the Inspector's calls, over stdio: tools/list, then a search and a where (the places guide
#: made session "yard"); a search may say "loading" while the models load behind initialize
INSPECTOR = """
import json, sys
import anyio
from mcp import Client, StdioServerParameters

async def ask(agent, name, args, said):
    while True:  # each request answered within the limit: an answer, or "loading: ..."
        r = await agent.call_tool(name, args)
        if not (r.is_error and "loading:" in r.content[0].text):
            return [r.is_error, r.content[0].text]
        said.append(r.content[0].text)
        await anyio.sleep(1.0)

async def main():
    server = StdioServerParameters(command="tactus", args=["mcp", "--data", "./memory"])
    said = []
    async with Client(server, read_timeout_seconds=float(sys.argv[1])) as agent:
        tools = [t.name for t in (await agent.list_tools()).tools]
        search = await ask(agent, "search", {"query": "picked up the drill", "k": 3}, said)
        where = await ask(agent, "where", {"query": "picked up the drill", "session": "yard"}, said)
    print(json.dumps({"tools": tools, "search": search, "where": where, "loading": said}))

anyio.run(main)
"""


def agent_calls(clone: Path, env: dict[str, str]) -> None:
    """The Inspector's calls against ``tactus mcp`` over stdio, each request within the
    Inspector's limit: initialize answers at once, the models load behind it
    (``examples/mcp_client.py`` itself runs as the MCP reference page's block)."""
    python = str(VENV / "bin" / "python")
    limit = str(AGENT_TIMEOUT_S)
    done = subprocess.run(
        [python, "-c", INSPECTOR, limit],
        cwd=clone, env=env, capture_output=True, text=True, timeout=BLOCK_S,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    got = json.loads(done.stdout.splitlines()[-1])
    assert {"search", "where", "at", "sessions"} <= set(got["tools"]), got
    assert not got["search"][0] and json.loads(got["search"][1])["hits"], got
    assert not got["where"][0] and json.loads(got["where"][1])["places"], got
    assert all("loading: the memory is still loading" in s for s in got["loading"]), got


def test_the_agent_example_grants_a_request_the_inspectors_limit() -> None:
    """``examples/mcp_client.py``, as the snippet test runs it (no arguments), waits for each
    request as long as the Inspector's CLI does, :data:`AGENT_TIMEOUT_S`, and no longer."""
    source = (ROOT / "examples" / "mcp_client.py").read_text()
    read = re.search(r'"--read-timeout", type=float, default=([0-9.]+)', source)
    assert read is not None, "examples/mcp_client.py has no --read-timeout"
    assert float(read.group(1)) == AGENT_TIMEOUT_S
    assert "read_timeout_seconds=opts.read_timeout" in source


def serving_processes(session: int) -> list[int]:
    """The ``tactus serve`` processes of the session ``make run`` leads."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue  # gone meanwhile
        if int(fields[3]) == session and b"serve" in cmdline and b"make" not in cmdline[0]:
            found.append(int(stat.parent.name))
    return found


def page_search(base: str, tmp_path: Path) -> None:
    """The page, as the newcomer opens it: a search lists hits, each with its match bar."""
    from tests.helpers.browser import launch, sync_playwright

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
            api_pages_render_offline(context, base)
        finally:
            context.close()


def api_pages_render_offline(context: Any, base: str) -> None:
    """``/docs`` (Swagger UI) and ``/redoc`` render with every request off the server
    refused: no script, stylesheet or font comes from elsewhere (Redoc's bundle still asks its
    vendor's CDN for the "API docs by Redocly" footer logo, an image; refused, it is left out)."""
    asked_elsewhere: list[str] = []

    def only_the_server(route: Any) -> None:
        if route.request.url.startswith(base + "/") or route.request.url.startswith("data:"):
            route.continue_()
        else:
            if route.request.resource_type != "image":
                asked_elsewhere.append(route.request.url)
            route.abort()

    context.route("**/*", only_the_server)
    page = context.new_page()
    page.set_default_timeout(60_000)
    page.goto(base + "/docs")
    page.wait_for_selector(".swagger-ui .opblock-summary-path")  # the operations, rendered
    assert "/search" in page.text_content(".swagger-ui")
    page.goto(base + "/redoc")
    page.wait_for_selector("redoc [role=menuitem], .menu-content label")  # its menu, rendered
    assert "Search every sense in natural language" in page.text_content("body")
    assert not asked_elsewhere, asked_elsewhere


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
    cmd = [sys.executable, "-c", hook, "serve", "--workers", "1", "--port", str(port)]
    cmd += ["--data", str(tmp_path / "m")]
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
    cmd += ["--workers", "1", "--port", str(free_port()), "--data", str(tmp_path / "m")]
    cmd += ["--touch-checkpoint", str(bad)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=STARTUP_S, env=shell_env(0))
    assert done.returncode == 2, done.stderr[-2000:]
    last = [ln for ln in done.stderr.splitlines() if ln.startswith("tactus serve:")]
    assert len(last) == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
