"""``tactus last | first | count | timeline`` and ``--url`` (issue 26): the memory's "when"
questions from the shell, on a store (HashingSpace, fast) and against a real uvicorn serving
the same store, which must answer alike; ``tactus --help`` groups the commands and shows
flags without a type."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

import tactus_memory.spaces as spaces
from benchmarks.serving import serve_app
from tactus_memory.cli import app
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.compare import alike
from tests.helpers.fakes import HashingSpace
from tests.helpers.kitchen import MUG_GRASPS, S, kitchen_notes

DIM = 64
#: a score computed in this process and in the server's can differ in its last bits (1e-7 seen)
SCORE_SLACK = 1e-6


def _space(*_a: object, **_k: object) -> HashingSpace:
    return HashingSpace(dim=DIM)


@pytest.fixture
def store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The kitchen's notes in a store the CLI reopens (its space resolved to HashingSpace)."""
    monkeypatch.setattr(spaces, "get_space", _space)
    path = tmp_path / "memory"
    mem = Memory.open(str(path), space=HashingSpace(dim=DIM), background=False)
    notes = kitchen_notes(delay=1.0 / 3.0)  # times like 10.333333: printed rounded
    mem.add_many(S, "text", [n for n, _ in notes], t=[t for _, t in notes])
    mem.add("other", "text", "a lone note", t=1.0)
    return path


def run(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(app, list(args))
    return res.exit_code, res.output


def test_last_first_count_timeline_on_a_store(store: Path) -> None:
    d = ["--data", str(store)]
    code, out = run("count", "the mug", "--session", S, "--json", *d)
    assert code == 0, out
    found = json.loads(out)
    assert found["count"] == 3
    assert [round(m["t"], 3) for m in found["moments"]] == [t + 0.333 for t in MUG_GRASPS]
    code, out = run("last", "the mug", "--session", S, "--json", *d)
    assert code == 0 and json.loads(out)["t"] == pytest.approx(MUG_GRASPS[-1] + 1 / 3)
    code, out = run("first", "the mug", "--session", S, *d)
    assert code == 0, out
    # rounded times in tables: 10.33, never 10.3333333
    assert "t 10.33 s" in out and "10.3333" not in out and "picked up the mug" in out
    code, out = run("count", "the mug", "--session", S, *d)
    assert code == 0 and "3 occurrences of 'the mug'" in out, out
    code, out = run("count", "dropped the can", "--session", S, *d)
    assert code == 0 and "1 occurrence of 'dropped the can'" in out, out
    code, out = run("last", "the weather in paris", "--session", S, *d)
    assert code == 0 and "nothing matches" in out, out
    # the same options as search: --sense narrows, --after/--before bound
    code, out = run("count", "the mug", "--after", "30", "--sense", "text", "--json", *d)
    assert code == 0 and json.loads(out)["count"] == 2
    code, out = run("timeline", S, "--json", *d)
    items = json.loads(out)
    assert code == 0 and len(items) == len(kitchen_notes(1.0)) and items[0]["t"] == 2.0
    code, out = run("timeline", S, "--episodes", "--json", *d)
    assert code == 0 and json.loads(out) and all("representative" in e for e in json.loads(out))
    # unknown session: one line, exit 2 (HTTP answers 404)
    code, out = run("last", "picked up the mug", "--session", "nope", *d)
    assert code == 2 and "no session 'nope'" in out, out
    code, out = run("sessions", *d)
    assert code == 0 and "2 sessions" in out
    code, out = run("search", "the mug", "--session", S, "--json", *d)
    hits = json.loads(out)
    assert code == 0 and hits[0]["match"] is True and hits[0]["bar"] >= 3.0
    assert any(h["match"] is False for h in hits)  # below the bar, still listed, and said so
    code, out = run("search", "mug", "--data", str(store), "--url", "http://127.0.0.1:9")
    assert code == 2 and "not both" in out


@pytest.fixture
def served(store: Path) -> Iterator[str]:
    """A real uvicorn on 127.0.0.1 serving that store (the lifespan warms the space)."""
    memory = Memory.open(str(store), space=HashingSpace(dim=DIM), background=False)
    app = create_app(Settings(data=str(store), touch=False), memory=memory)
    with serve_app(app, probe="/ready") as base:
        yield base


@pytest.mark.parametrize(
    "args",
    [
        ["search", "picked up the mug", "--k", "5"],
        ["last", "picked up the mug", "--session", S],
        ["first", "picked up the mug"],
        ["count", "picked up the mug", "--after", "50", "--sense", "text"],
        ["timeline", S, "--before", "40"],
        ["timeline", S, "--episodes"],
        ["sessions"],
    ],
)
def test_url_answers_like_the_store(store: Path, served: str, args: list[str]) -> None:
    local = run(*args, "--json", "--data", str(store))
    remote = run(*args, "--json", "--url", served)
    assert local[0] == remote[0] == 0, (local, remote)
    assert alike(json.loads(local[1]), json.loads(remote[1]), SCORE_SLACK)
    assert json.loads(remote[1])  # something was answered


def test_url_errors_are_one_line(served: str) -> None:
    code, out = run("last", "mug", "--session", "nope", "--url", served)
    assert code == 2 and "404" in out and "nope" in out, out
    code, out = run("search", "mug", "--url", "http://127.0.0.1:9")
    assert code == 2 and "cannot reach the server" in out, out


def test_url_mode_loads_no_model(served: str) -> None:
    """With --url nothing heavy is imported: no torch, no LanceDB (so no model load)."""
    code = (
        "import atexit, sys\n"
        "atexit.register(lambda: print('HEAVY', sorted(m for m in ('torch', 'lancedb') "
        "if m in sys.modules)))\n"
        "from tactus_memory.cli import main\n"
        "main()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, "count", "the mug", "--url", served],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "3 occurrences" in done.stdout and "HEAVY []" in done.stdout, done.stdout


def test_help_groups_commands_and_shows_plain_flags() -> None:
    code, out = run("--help")
    assert code == 0
    order = ["Serve and maintain", "Ask the memory", "Recordings", "Data sets", "Touch encoder"]
    where = [out.index(title) for title in order]
    assert where == sorted(where), out
    asked = out[out.index("Ask the memory") : out.index("Recordings")]
    for name in ("search", "last", "first", "count", "timeline", "sessions"):
        assert f" {name} " in asked, (name, asked)
    for sub in (["ingest"], ["search"], ["timeline"], ["data", "fetch"]):
        code, out = run(*sub, "--help")
        assert code == 0 and "<bool>" not in out, out
    assert "--episodes" in run("timeline", "--help")[1]


def test_tenant_chooses_whose_memory_locally_and_over_url(store: Path, served: str) -> None:
    """``--tenant`` on the commands that open a store (and sent as the operator's tenant
    header with --url); a tenant that does not exist is an error, not a new tenant."""
    mem = Memory.open(str(store), space=HashingSpace(dim=DIM), tenant="A", background=False)
    mem.add("a-only", "text", "the tenant's own mug", t=2.0)
    for args in (["sessions"], ["search", "mug", "--k", "5"], ["count", "mug"]):
        local = run(*args, "--json", "--tenant", "A", "--data", str(store))
        remote = run(*args, "--json", "--tenant", "A", "--url", served)
        assert local[0] == remote[0] == 0, (args, local, remote)
        assert alike(json.loads(local[1]), json.loads(remote[1]), SCORE_SLACK), args
        assert S not in local[1] and "other" not in local[1], (args, local[1])
    assert [s["id"] for s in json.loads(run("sessions", "--json", "--tenant", "A",
                                            "--data", str(store))[1])] == ["a-only"]  # fmt: skip
    assert "a-only" not in run("sessions", "--json", "--data", str(store))[1]
    code, out = run("sessions", "--tenant", "tpyo", "--data", str(store))
    assert code == 2 and "no tenant 'tpyo'" in out, out
    assert not (store / "tenants" / "tpyo").exists()
    code, out = run("sessions", "--tenant", "tpyo", "--url", served)
    assert code == 2 and "404" in out and "tpyo" in out, out
