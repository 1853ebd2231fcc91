"""A young sense's estimate is blended with its shipped prior (``search.scoring.blend``) until
it is final (issue 46); the shipped touch priors on the real path: tests/touch/
test_match_precision.py."""

from __future__ import annotations

import pytest

from tactus_memory.search.scoring import FINAL_ROWS, Calibration, blend


def test_blend_moves_from_the_prior_to_the_own_estimate() -> None:
    prior = Calibration(mu=0.1, sigma=0.1)
    young = blend(Calibration(mu=0.5, sigma=0.3, n=FINAL_ROWS // 4), prior)
    assert young.mu == pytest.approx(0.2) and young.sigma == pytest.approx(0.15)
    final = Calibration(mu=0.5, sigma=0.3, n=FINAL_ROWS)
    assert blend(final, prior) == final  # a final estimate is the store's own
    assert blend(Calibration(mu=0.5, sigma=0.3, n=7), None).mu == 0.5  # no prior: own alone
