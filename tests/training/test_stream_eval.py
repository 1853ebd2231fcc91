"""Stream evaluation (tactus_memory.training.stream_eval): real STAG recordings, real MiniLM,
real LanceDB memory, the shipped checkpoint; plus the CLI's ``--stream``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.targets import class_phrases
from tactus_memory.training.data import combine, load_stag
from tactus_memory.training.stream_eval import (
    build_stream,
    load_queries,
    run_stream_eval,
    template_collisions,
)
from tactus_memory.training.train import holdout_recordings

pytestmark = pytest.mark.slow

HOLDOUT = "one-per-object@blindfolded"


@pytest.fixture(scope="module")
def stag(stag_dir):
    return combine(
        [load_stag(stag_dir / "weights_lite"), load_stag(stag_dir / "blindfolded_lite_train")]
    )


def test_queries_cover_every_class_and_are_not_templates(stag) -> None:
    q = load_queries()
    assert set(q) == set(stag.objects)
    assert all(len(v) >= 3 and len(set(v)) == len(v) for v in q.values())
    assert template_collisions(q) == []
    # the check itself bites: a training phrase is caught
    assert template_collisions({"mug": [class_phrases("mug")[1].upper()]}) != []


def test_bad_queries_file_is_a_typed_error(tmp_path) -> None:
    p = tmp_path / "q.json"
    p.write_text(json.dumps({"queries": {"mug": []}}))
    with pytest.raises(InvalidInputError, match="mug"):
        load_queries(p)


def test_build_stream_lays_recordings_end_to_end(stag) -> None:
    recs = holdout_recordings(stag, HOLDOUT)[:3]
    st = build_stream(stag, recs)
    assert len(st.spans) == 3 and st.frames.shape[1:] == (8, 32, 32)
    spans = sorted(st.spans.values())
    assert all(b[0] - a[1] >= 10.0 for a, b in zip(spans, spans[1:], strict=False))
    for name, (a, b) in st.spans.items():
        mine = np.asarray(st.recording) == name
        assert (st.t[mine] >= a).all() and (st.t_end[mine] <= b).all()
    assert st.idle.any() and (~st.idle).any()


def test_short_stream_eval_on_real_stag(stag, minilm_space) -> None:
    out = run_stream_eval(None, stag, HOLDOUT, limit=4, space=minilm_space)
    # its 4 classes + the empty hand (no recording in the split): 5 x 3 phrasings
    assert out["n_recordings"] == 4 and out["n_queries"] == 15
    # the shipped checkpoint was trained on every recording: the check must say so
    assert out["leakage"]["status"] == "overlap"
    served, every = out["served"], out["all_windows"]
    assert served["idle_windows_stored"] == 0
    assert every["idle_windows_stored"] == out["idle_windows"] > 0
    assert served["queries_scored"] == 12  # 4 classes x 3 phrasings
    for m in (served, every):
        for key in ("r@1", "r@5", "mrr", "match_other_object_rate", "last_correct"):
            assert 0.0 <= m[key] <= 1.0
        assert m["r@1"] <= m["r@5"]
        assert len(m["per_class"]) == 4
    # four recordings the model was trained on, 4-way: the named one must rank high
    assert served["r@5"] == 1.0 and served["mrr"] > 0.5
    assert every["match_idle_rate"] is not None and served["match_idle_rate"] is None
    assert 0.0 <= served["absent_class_count_zero"] <= 1.0


def test_cli_eval_stream(stag_dir, tmp_path) -> None:
    from tactus_memory.cli import app

    out = tmp_path / "eval.json"
    res = CliRunner().invoke(
        app,
        [
            "eval", "--checkpoint", "default",
            "--data", str(stag_dir / "weights_lite"),
            "--data", str(stag_dir / "blindfolded_lite_train"),
            "--holdout", HOLDOUT, "--no-analysis", "--votes", "1",
            "--stream", "--stream-limit", "2",
            "--json", str(out), "--report", str(tmp_path / "rep"),
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    payload = json.loads(out.read_text())
    assert payload["stream"]["n_recordings"] == 2
    assert payload["stream"]["served"]["queries_scored"] == 6  # 2 classes x 3 phrasings
    assert "Stream evaluation" in (tmp_path / "rep" / "stream.md").read_text()


def test_cli_stream_needs_holdout(stag_dir, tmp_path) -> None:
    from tactus_memory.cli import app

    res = CliRunner().invoke(
        app,
        ["eval", "--checkpoint", "default", "--data", str(stag_dir / "weights_lite"),
         "--stream", "--json", str(tmp_path / "e.json")],
    )  # fmt: skip
    assert res.exit_code != 0 and "--holdout" in res.output
