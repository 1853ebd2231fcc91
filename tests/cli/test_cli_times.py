"""Issue 48 on the CLI: every command that takes a time (``--after``/``--before`` of search,
last, first, count, timeline and teach), against a real uvicorn (``--url``, the Client) and on
a store (``--data``), is sent the edge values: each answers (exit 0), or refuses in one line
with exit 2, never a traceback. Defect 8: ``tactus teach X --session S --after nan --url URL
--token K`` printed 150 lines and exited 1."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

import tactus_memory.spaces as spaces
from benchmarks.serving import serve_app
from tactus_memory.cli import app
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.fakes import HashingSpace
from tests.helpers.service import DIM, make_memory, window

#: the issue's edge values as a shell passes them (text); "true" is not a number for click
EDGES = ["0", "-0.0", "5e-324", "1e9", "1.7e18", "1e308", "inf", "-inf", "nan", "true", "3"]
KEPT = {"0", "-0.0", "5e-324", "1e9", "3"}
S = "edge"
#: every command that takes a time: its arguments and the time's option (--after and
#: --before of a command are one option type, cli/common.py: After, Before)
COMMANDS = [
    ["search", "holding a mug", "--after"],
    ["last", "holding a mug", "--before"],
    ["first", "holding a mug", "--after"],
    ["count", "holding a mug", "--before"],
    ["timeline", S, "--after"],
    ["teach", "mug", "--session", S, "--after"],
    ["teach", "mug", "--session", S, "--before"],
]


@pytest.fixture(scope="module")
def url(tmp_path_factory) -> Iterator[str]:
    memory = make_memory(tmp_path_factory.mktemp("cli-times") / "mem")
    memory.add(S, "touch", window(seed=3), t=2.0, t_end=2.5)
    memory.add(S, "text", "picked up the mug", t=2.0)
    with serve_app(create_app(Settings(token="k"), memory=memory)) as base:
        yield base


def run(*args: str) -> tuple[int, str, BaseException | None]:
    res = CliRunner().invoke(app, list(args))
    return res.exit_code, res.output, res.exception


def _one_line_refusal(code: int, out: str, exc: BaseException | None, value: str) -> None:
    assert code == 2, (code, out, exc)
    assert "Traceback" not in out and not isinstance(exc, (TypeError, ValueError)), out
    if value != "true":  # click's own usage error for a non-number (several lines, exit 2)
        assert len([ln for ln in out.splitlines() if ln.strip()]) == 1, out
    if value == "1.7e18":
        assert "seconds, not nanoseconds?" in out, out


@pytest.mark.parametrize("value", EDGES)
def test_every_time_option_over_url(url: str, value: str) -> None:
    for command in COMMANDS:
        code, out, exc = run(*command, value, "--url", url, "--token", "k")
        if value in KEPT:
            # answers, or (teach) refuses a span with no window in one line
            assert code == 0 or (command[0] == "teach" and code == 2), (command, out, exc)
            assert "Traceback" not in out
        else:
            _one_line_refusal(code, out, exc, value)


def test_teach_after_nan_on_a_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The library path refuses as the Client does (one line, exit 2)."""
    monkeypatch.setattr(spaces, "get_space", lambda *_a, **_k: HashingSpace(dim=DIM))
    memory = make_memory(tmp_path / "mem", touch=False)
    memory.add(S, "text", "a note", t=1.0)
    memory.close()
    for value in ("nan", "1.7e18"):
        code, out, exc = run("teach", "mug", "--session", S, "--after", value, "--data",
                             str(tmp_path / "mem"))  # fmt: skip
        _one_line_refusal(code, out, exc, value)
