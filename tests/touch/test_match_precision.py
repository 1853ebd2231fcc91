"""What a touch match means, and a young touch memory's prior (issue 46): ``GET /senses``
reports the measured precision of a match at the bar for the shipped checkpoints
(``benchmarks/touch_demo.py``), and the touch sense carries the prior calibration shipped for
its checkpoint (``benchmarks/calibration_prior.py``). Real MiniLM, the shipped encoders."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.matching import GRASP_MATCH_Z
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.touch.checkpoint import (
    CALIBRATION_PRIORS,
    MATCH_PRECISION,
    default_checkpoint_path,
    demo_checkpoint_path,
)

pytestmark = pytest.mark.slow


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
    text = senses.get("text")
    assert text is None or text["precision_at_bar"] is None  # none measured: null, not made up


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
