"""An agent's first calls to ``tactus mcp``, as an MCP client makes them: how long from
starting the server to ``initialize``'s answer, and from there to the first tool calls.

Each round starts a fresh ``tactus mcp`` on the same small store (three notes, written once
before the rounds by the same command with ``--allow-writes``; MiniLM's ONNX graph is in the
user's cache, as after ``make run``'s first start) and records, in seconds:

* stdio (the MCP SDK's client starts ``tactus mcp --data DIR`` itself):
  ``initialize_s`` from the start to ``initialize``'s answer; then, each from the previous
  answer, ``tools_list_s``, ``sessions_s`` (a tool that needs no model), ``search_first_s``
  (the first ``search``: its answer, or the tool error ``loading: ...`` while the models load
  behind, ``search_first_loading`` says which), and ``search_answer_s`` (from ``initialize``
  until a ``search`` answers with hits, asked again each second while it says loading);
* HTTP (``tactus mcp --http``, which loads the models before its port answers):
  ``port_s`` from the start until ``/mcp`` accepts a connection, then ``initialize_s``,
  ``sessions_s`` and ``search_first_s`` as above.

The machine's 1- and 5-minute load at the start and end of each round, its cores, and whether
torch was importable are recorded with the figures. ``--no-torch`` makes torch,
sentence-transformers and transformers unimportable in the servers (``benchmarks.serving
.NO_TORCH``), as in ``make run``'s venv.

    python benchmarks/mcp_first_call.py --rounds 5 --no-torch

Results are appended to ``benchmarks/results/mcp_first_call.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import anyio
import httpx
from mcp import Client, StdioServerParameters

from serving import free_port, stop_process, without_torch

RESULTS = Path(__file__).resolve().parent / "results" / "mcp_first_call.json"
#: what each request may take: the MCP Inspector's CLI's limit (tests/project/test_newcomer.py)
REQUEST_S = 30.0
#: how long a search may keep answering "loading" before the round is recorded as failed
LOADING_GIVE_UP_S = 600.0
NOTES = ["picked up the red mug", "put the drill on the shelf", "the kettle is on the stove"]
SESSION = "bench"
QUERY = {"query": "holding a mug", "k": 3}


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()[:2]]


def tactus_command() -> str:
    found = shutil.which("tactus", path=str(Path(sys.executable).parent))
    return found or shutil.which("tactus") or "tactus"


async def until_answer(agent: Client, name: str, args: dict[str, Any]) -> tuple[float, Any]:
    """Ask ``name`` again each second while it says "loading"; (seconds, the answer)."""
    t0 = time.monotonic()
    while True:
        answer = await agent.call_tool(name, args)
        loading = answer.is_error and "loading:" in answer.content[0].text
        if not loading or time.monotonic() - t0 > LOADING_GIVE_UP_S:
            return time.monotonic() - t0, answer
        await anyio.sleep(1.0)


async def first_calls(agent: Client, out: dict[str, Any]) -> None:
    """``sessions`` (no model), then the first ``search`` (an answer, or "loading"), each
    timed from the previous answer, into ``out``."""
    t = time.monotonic()
    sessions = await agent.call_tool("sessions", {})
    assert not sessions.is_error, sessions.content[0].text
    out["sessions_s"], t = round(time.monotonic() - t, 2), time.monotonic()
    first = await agent.call_tool("search", QUERY)
    out["search_first_s"] = round(time.monotonic() - t, 2)
    out["search_first_loading"] = first.is_error and "loading:" in first.content[0].text


async def fill(command: str, data: Path) -> None:
    server = StdioServerParameters(
        command=command, args=["mcp", "--data", str(data), "--allow-writes"], env=dict(os.environ)
    )
    async with Client(server, read_timeout_seconds=REQUEST_S) as agent:
        for i, text in enumerate(NOTES):
            _, answer = await until_answer(
                agent, "remember", {"session": SESSION, "text": text, "t": float(i)}
            )
            assert not answer.is_error, answer.content[0].text


async def stdio_round(command: str, data: Path) -> dict[str, Any]:
    server = StdioServerParameters(
        command=command, args=["mcp", "--data", str(data)], env=dict(os.environ)
    )
    out: dict[str, Any] = {"load_1_5min_at_start": load()}
    t0 = time.monotonic()
    async with Client(server, read_timeout_seconds=REQUEST_S) as agent:
        ready = time.monotonic()
        out["initialize_s"] = round(ready - t0, 2)
        t = time.monotonic()
        await agent.list_tools()
        out["tools_list_s"] = round(time.monotonic() - t, 2)
        await first_calls(agent, out)
        _, answer = await until_answer(agent, "search", QUERY)
        assert not answer.is_error and json.loads(answer.content[0].text)["hits"], answer
        out["search_answer_s"] = round(time.monotonic() - ready, 2)
    out["load_1_5min_at_end"] = load()
    return out


async def http_round(command: str, data: Path, log: Path) -> dict[str, Any]:
    port = free_port()
    out: dict[str, Any] = {"load_1_5min_at_start": load()}
    args = [command, "mcp", "--http", "--port", str(port), "--data", str(data)]
    t0 = time.monotonic()
    with log.open("ab") as fh:
        proc = subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}/mcp"
    try:
        while True:  # the port answers (any status) once the models are in
            if proc.poll() is not None:
                raise RuntimeError(f"tactus mcp --http exited ({proc.returncode}): see {log}")
            try:
                httpx.get(url, timeout=2)
                break
            except httpx.TransportError:
                await anyio.sleep(0.1)
        out["port_s"] = round(time.monotonic() - t0, 2)
        t = time.monotonic()
        async with Client(url, read_timeout_seconds=REQUEST_S) as agent:
            out["initialize_s"] = round(time.monotonic() - t, 2)
            await first_calls(agent, out)
    finally:
        stop_process(proc)
    out["load_1_5min_at_end"] = load()
    return out


def summary(rounds: list[dict[str, Any]]) -> dict[str, Any]:
    keys = [k for k, v in rounds[0].items() if k.endswith("_s") and isinstance(v, float)]
    return {k: {"min": min(r[k] for r in rounds), "max": max(r[k] for r in rounds)} for k in keys}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--no-torch", action="store_true", help="as make run's venv: no torch")
    ap.add_argument("--note", default=None, help="recorded with the run (what was measured)")
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mcp-first-call-") as tmp:
        work = Path(tmp)
        command = tactus_command()
        if opts.no_torch:
            env = without_torch(dict(os.environ), work / "no-torch", Path(command))
            os.environ.update(env)
            command = str(work / "no-torch" / "bin" / "tactus")
        data = work / "memory"
        data.mkdir()  # `tactus mcp` opens a store, it does not make one up from a typo
        anyio.run(fill, command, data)
        stdio = [anyio.run(stdio_round, command, data) for _ in range(opts.rounds)]
        http = [anyio.run(http_round, command, data, work / "http.log") for _ in range(opts.rounds)]
        probe = subprocess.run(  # as the servers ran (the sitecustomize is in ``work``)
            [sys.executable, "-c", "import torch"], env=dict(os.environ), capture_output=True
        )
    run = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "code": opts.note,
        "cores": os.cpu_count(),
        "torch_importable": probe.returncode == 0,
        "rounds": opts.rounds,
        "stdio": {"summary": summary(stdio), "rounds": stdio},
        "http": {"summary": summary(http), "rounds": http},
    }
    RESULTS.parent.mkdir(exist_ok=True)
    past = json.loads(RESULTS.read_text())["runs"] if RESULTS.exists() else []
    RESULTS.write_text(json.dumps({"runs": [*past, run]}, indent=1) + "\n")
    print(json.dumps({"stdio": run["stdio"]["summary"], "http": run["http"]["summary"]}, indent=1))


if __name__ == "__main__":
    main()
