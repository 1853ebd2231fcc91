"""``tactus demo`` (issues 38, 46): touch answering questions whose right answers are known, on
the real STAG files (recordings the demo checkpoint never trained on, real MiniLM, a real
store), and the notes part alone, with one line saying how to get the files, when they are
absent. Right means the top hit is the right span or note AND a match."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.cli import app
from tactus_memory.cli.demo_cmd import (
    HELDOUT_FIGURES,
    NOTE_QUESTIONS,
    RIGHT,
    SESSION,
    SUBSET,
    TOUCH_QUESTIONS,
    demo_recordings,
)

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
    assert lines[-1] == f"{len(NOTE_QUESTIONS)} of {len(NOTE_QUESTIONS)} right ({RIGHT})"
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
    assert all(a["match"] == "yes" for a in got if a["right"] == "yes"), res.output
    right = sum(a["right"] == "yes" for a in got)
    lines = res.output.splitlines()
    assert lines[-2] == f"{right} of 5 right ({RIGHT})"
    # the held-out figures the demo prints are the measured ones (benchmarks/touch_demo.py)
    fig = json.loads(HELDOUT_FIGURES.read_text())
    assert f"R@5 {fig['stream_r5']['value']:.2f}" in lines[-1], lines[-1]
    assert f"tuple top-1 {fig['tuple_top1']['value']:.2f}" in lines[-1], lines[-1]
    # the session holds the three recordings' contact windows (idle ones skipped) and the notes
    counts = re.search(r"session '[^']+': (\d+) text, (\d+) touch", res.output)
    assert counts and int(counts[1]) == len(NOTE_QUESTIONS) and int(counts[2]) > 10, res.output


def test_the_demo_recordings_were_never_trained_on_by_its_checkpoint(stag_subset) -> None:
    """The demo checkpoint's recorded holdout names the demo's recordings, and the recordings it
    trained on (every recording of its fingerprinted data with valid frames, minus the held-out
    ones) do not include them."""
    from tactus_memory.touch.checkpoint import (
        demo_checkpoint_path,
        heldout_recordings,
        load_checkpoint,
    )
    from tactus_memory.training.train import load_data

    meta = load_checkpoint(demo_checkpoint_path(), weights=False).meta
    held = set(heldout_recordings(meta))
    assert len(held) == 26, held  # one blindfolded recording per object
    blind = stag_subset(SUBSET)
    trained_on = load_data([blind.parent / "weights_lite", blind])
    assert trained_on.fingerprint() == meta["data_fingerprint"]  # the names are of this data
    seen = {
        trained_on.recordings[int(r)]
        for r in np.unique(trained_on.recording_id[trained_on.valid])
        if trained_on.recordings[int(r)] not in held
    }
    data = load_data([blind])
    recs = demo_recordings(data, meta)
    assert sorted(recs) == sorted(obj for obj, _ in TOUCH_QUESTIONS)
    names = [data.recordings[r] for r in recs.values()]
    assert set(names) <= held and not set(names) & seen, (names, sorted(seen))
    for obj, r in recs.items():  # each is a recording of the object it is asked about
        assert data.objects[int(data.object_id[data.recording_id == r][0])] == obj
