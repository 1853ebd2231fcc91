"""The rule that chooses a match bar from held-out questions (``training/bar_rule.py``): the
lowest bar whose precision's Wilson lower bound reaches the target, or none, said so."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.training.bar_rule import TARGET_PRECISION, choose_bar, senses_row, wilson


def test_the_lowest_bar_whose_lower_bound_reaches_the_target() -> None:
    # 30 right top hits scoring 5-8, 10 wrong ones scoring 2-4.5 (2.0, 2.28, ... 4.22, 4.5)
    scores = np.r_[np.linspace(5.0, 8.0, 30), np.linspace(2.0, 4.5, 10)]
    right = np.r_[np.ones(30, bool), np.zeros(10, bool)]
    got = choose_bar(scores, right, shipped_bar=3.0)
    # at 4.0: 30 of 32, point estimate 0.94 but lower bound 0.799: not taken (nor 3.0's 0.83)
    assert got["sweep"]["4.0"]["value"] > TARGET_PRECISION > got["sweep"]["4.0"]["lo"]
    assert got["sweep"]["3.0"]["value"] > TARGET_PRECISION
    # at 4.5: 30 of 31, lower bound 0.838: the bar
    assert got["target_reached"] and got["bar_at_target"] == 4.5
    assert (got["sweep"]["4.5"]["k"], got["sweep"]["4.5"]["n"]) == (30, 31)
    assert (got["at_shipped_bar"]["k"], got["at_shipped_bar"]["n"]) == (30, 36)


def test_a_few_right_matches_do_not_reach_the_target_and_the_row_says_so() -> None:
    got = choose_bar([7.0, 6.0, 5.0, 1.0], [True, True, True, False], shipped_bar=3.0)
    assert got["sweep"]["3.0"]["value"] == 1.0  # 3 of 3 right ...
    assert got["sweep"]["3.0"]["lo"] < TARGET_PRECISION  # ... lower bound 0.44: not taken
    assert not got["target_reached"] and got["bar_at_target"] is None
    row = senses_row(got, "four questions", "a test")
    assert row["target_reached"] is False and row["bar"] == 3.0 and row["k"] == 3
    assert row["questions"] == "four questions" and "Wilson" in row["rule"]


def test_wilson_and_bad_shapes() -> None:
    w = wilson(8, 10)
    assert w["lo"] < 0.8 < w["hi"] and w["value"] == 0.8
    assert wilson(0, 0)["value"] is None
    with pytest.raises(ValueError, match="two"):
        choose_bar([1.0, 2.0], [True], shipped_bar=3.0)
