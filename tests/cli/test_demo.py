"""``tactus demo`` (issue 38): touch answering questions whose right answers are known, on
the real STAG files (held-out recordings, the shipped encoder, real MiniLM, a real store), and
the notes part alone, with one line saying how to get the files, when they are absent."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from tactus_memory.cli import app
from tactus_memory.cli.demo_cmd import NOTE_QUESTIONS, SESSION, TOUCH_QUESTIONS

pytestmark = pytest.mark.slow

LINE = re.compile(
    r"^'(?P<q>[^']+)': hit (?P<sense>\w+) (?P<t>[\d.]+)-(?P<t_end>[\d.]+) s.*  "
    r"score (?P<score>-?[\d.]+)  match (?P<match>yes|no) \(bar (?P<bar>-?[\d.]+)\)  "
    r"right: (?P<right>yes|no)$"
)


def answers(output: str) -> list[dict[str, str]]:
    return [m.groupdict() for line in output.splitlines() if (m := LINE.match(line))]


def test_demo_without_stag_says_how_to_get_it_and_asks_the_notes(tmp_path) -> None:
    store = tmp_path / "demo"
    args = ["demo", "--from", str(tmp_path / "nothing"), "--data", str(store)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert "tactus data fetch stag" in lines[0] and "notes only" in lines[0]
    got = answers(res.output)
    assert [a["q"] for a in got] == [q for q, _ in NOTE_QUESTIONS]
    assert all(a["sense"] == "text" and a["right"] == "yes" for a in got), res.output
    assert all((a["match"] == "yes") == (float(a["score"]) >= float(a["bar"])) for a in got)
    assert lines[-1] == f"{len(NOTE_QUESTIONS)} of {len(NOTE_QUESTIONS)} right"
    assert f"session '{SESSION}': {len(NOTE_QUESTIONS)} text" in res.output
    from tactus_memory.memory.main import Memory

    kept = Memory.open(str(store), background=False)  # --data keeps the session
    assert kept.session(SESSION).counts == {"text": len(NOTE_QUESTIONS)}


def test_demo_on_the_stag_files_asks_five_questions(stag_dir) -> None:
    res = CliRunner().invoke(app, ["demo", "--from", str(stag_dir)])
    assert res.exit_code == 0, res.output
    assert "tactus data fetch stag" not in res.output
    got = answers(res.output)
    print(res.output)
    assert [a["q"] for a in got] == [q for _, q in TOUCH_QUESTIONS] + [q for q, _ in NOTE_QUESTIONS]
    touch, notes = got[: len(TOUCH_QUESTIONS)], got[len(TOUCH_QUESTIONS) :]
    assert all(a["sense"] == "touch" for a in touch) and all(a["sense"] == "text" for a in notes)
    assert all(a["right"] == "yes" for a in notes), res.output
    assert all((a["match"] == "yes") == (float(a["score"]) >= float(a["bar"])) for a in got)
    right = sum(a["right"] == "yes" for a in got)
    assert res.output.splitlines()[-1] == f"{right} of 5 right"
    # the session holds the three recordings' contact windows (idle ones skipped) and the notes
    counts = re.search(r"session '[^']+': (\d+) text, (\d+) touch", res.output)
    assert counts and int(counts[1]) == len(NOTE_QUESTIONS) and int(counts[2]) > 10, res.output
