"""CLI smoke tests (issue 16): ``tactus pretrain``, ``train``, ``eval`` and ``ablate`` run
end to end through Typer's CliRunner on tiny synthetic STAG files (tests/helpers/stag_synth.py),
with
the real MiniLM space for the targets, and leave what they promise: checkpoints that load,
held-out numbers in range, an ablation table with every row."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tactus_memory.cli import app
from tests.helpers.training import HOLDOUT, _last_json, _run


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("runs")
    common = ["--model", "tactus-tiny", "--threads", "1", "--holdout", HOLDOUT]
    mae = d / "mae.safetensors"
    out = _run(["pretrain", *data, "--out", str(mae), "--steps", "3", "--batch", "8", *common])
    s = _last_json(out)
    assert s["pretrain"]["steps"] == 3 and math.isfinite(s["final_loss"])
    assert len(s["excluded_recording_names"]) == 27  # held-out recordings kept out of MAE
    ck = d / "touch.safetensors"
    args = ["train", *data, "--out", str(ck), "--pretrained", str(mae), "--steps", "3"]
    out = _run([*args, "--batch", "8", *common])
    s = _last_json(out)
    assert s["steps"] == 3
    assert s["heldout"]["recordings"] == 27 and 0.0 <= s["heldout"]["top1"] <= 1.0
    return {"mae": mae, "touch": ck, "dir": d}


def test_pretrain_and_train_write_loadable_checkpoints(trained) -> None:
    from tactus_memory.adapters.touch import TactusEncoder

    assert trained["mae"].is_file() and trained["touch"].is_file()
    enc = TactusEncoder(trained["touch"])
    assert enc.dim == 384 and enc.space_name == "minilm-l6" and len(enc.classes) == 27


def test_eval_scores_the_heldout_recordings(trained, data) -> None:
    from tests.helpers.metric_checks import check_metrics

    js = trained["dir"] / "eval.json"
    ck = str(trained["touch"])
    _run(["eval", "--checkpoint", ck, *data, "--holdout", HOLDOUT, "--json", str(js)])
    m = json.loads(js.read_text())
    assert m["n_recordings"] == 27
    check_metrics(m)


def test_ablate_runs_every_row(data, tmp_path) -> None:
    js = tmp_path / "ablation.json"
    rows = "recipe,random_tuples"
    args = ["ablate", *data, "--json", str(js), "--steps", "2", "--seeds", "1"]
    out = _run([*args, "--model", "tactus-tiny", "--batch", "8", "--rows", rows])
    res = json.loads(js.read_text())
    assert res["complete"] is True
    text = json.dumps(res)
    for row in rows.split(","):
        assert row in text and row in out


@pytest.mark.parametrize(
    ("flag", "value"), [("--positives", "all"), ("--balance", "objects"), ("--augment", "wild")]
)
def test_train_refuses_an_unknown_ladder_option_up_front(data, tmp_path, flag, value) -> None:
    out = tmp_path / "never.safetensors"
    r = CliRunner().invoke(app, ["train", *data, "--out", str(out), flag, value])
    assert r.exit_code == 2  # a usage error, before any data is read
    assert flag in r.output and value in r.output
    assert not out.exists()
