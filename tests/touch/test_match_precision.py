"""What a match means, and a young touch memory's prior (issue 46): ``GET /senses`` reports the
measured precision of a match at the bar for the shipped checkpoints
(``benchmarks/touch_demo.py``) and for the MiniLM text sense (``benchmarks/text_precision.py``),
each the rule of ``training/bar_rule.py`` applied to the benchmark's stored top hits; the
touch sense carries the prior calibration shipped for its checkpoint
(``benchmarks/calibration_prior.py``). Real MiniLM, the shipped encoders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.matching import GRASP_MATCH_Z, MATCH_Z
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.spaces.figures import MATCH_PRECISION as TEXT_PRECISION
from tactus_memory.spaces.figures import figures_path
from tactus_memory.touch.checkpoint import (
    CALIBRATION_PRIORS,
    MATCH_PRECISION,
    default_checkpoint_path,
    demo_checkpoint_path,
)
from tactus_memory.training.bar_rule import choose_bar, senses_row

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def rule_on(result: str, key: str) -> dict:
    """The bar rule applied again to the top hits a benchmark stored (``benchmarks/results``)."""
    bars = json.loads((ROOT / "benchmarks/results" / result).read_text())[key]
    rows = bars["rows"]
    return choose_bar([r["score"] for r in rows], [r["right"] for r in rows], bars["shipped_bar"])


def test_senses_reports_the_precision_of_a_touch_match(tmp_path, minilm_space) -> None:
    measured = json.loads((default_checkpoint_path().parent / MATCH_PRECISION).read_text())
    mem = Memory.open(str(tmp_path / "m"), space=minilm_space, background=False)
    mem.add_sense(TactusEncoder(demo_checkpoint_path()))
    with TestClient(create_app(Settings(), memory=mem)) as c:
        senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
    got = senses["touch"]["precision_at_bar"]
    want = measured["precision_at_bar"][TactusEncoder(demo_checkpoint_path()).ckpt.sha256]
    assert got == want
    assert got["bar"] == GRASP_MATCH_Z["touch"]  # the bar a grasp match is judged by
    assert got["lo"] <= got["value"] <= got["hi"] and got["n"] > 0
    assert "held-out" in got["measured_on"] and got["questions"]
    # the row is the rule's answer on the benchmark's own top hits: no bar reaches the target,
    # and /senses says so rather than naming one
    redo = rule_on("touch_demo.json", "precision_at_bar")
    assert got == senses_row(redo, got["questions"], got["measured_on"])
    assert got["target_reached"] is False and got["bar_at_target"] is None
    # the text sense: measured on paraphrase questions in a grown memory, the same rule
    text = senses["text"]["precision_at_bar"]
    assert (
        text
        == json.loads(figures_path(TEXT_PRECISION).read_text())["precision_at_bar"][
            minilm_space.name
        ]["text"]
    )
    redo = rule_on("text_precision.json", "grown")
    assert text == senses_row(redo, text["questions"], text["measured_on"])
    assert text["bar"] == MATCH_Z["text"] and text["lo"] <= text["value"] <= text["hi"]


def test_each_shipped_checkpoint_has_a_prior_calibration(tmp_path, minilm_space) -> None:
    priors = json.loads((default_checkpoint_path().parent / CALIBRATION_PRIORS).read_text())
    for path in (default_checkpoint_path(), demo_checkpoint_path()):
        enc = TactusEncoder(path)
        row = priors["priors"][enc.ckpt.sha256]
        assert enc.calibration_prior() == {"mu": row["mu"], "sigma": row["sigma"]}
        assert row["windows"] >= 1000 and row["sigma"] > 0
    mem = Memory.open(str(tmp_path / "m"), space=minilm_space, background=False)
    mem.add_sense(TactusEncoder(demo_checkpoint_path()))
    prior = mem.registry.prior("touch")
    assert prior is not None and prior.mu == row["mu"]
    assert mem.calibration("touch").mu == pytest.approx(row["mu"])  # no rows yet: the prior
