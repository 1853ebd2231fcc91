"""Value checks for an evaluation JSON (``tactus eval`` / ``tactus baseline eval``): not only
that the keys exist, but that the numbers are consistent with one another."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest


def check_metrics(m: dict[str, Any]) -> None:
    for a, b in (("top1", "top3"), ("top1_vote", "top3_vote")):
        assert 0.0 <= m[a] <= m[b] <= 1.0, (a, m[a], b, m[b])
    n_rec = m["n_recordings"]
    assert n_rec >= 1
    # recording-level accuracy is a fraction of whole recordings
    assert m["recording_top1"] * n_rec == pytest.approx(round(m["recording_top1"] * n_rec))
    conf = np.asarray(m["confusion"], dtype=float)
    assert conf.shape[0] == conf.shape[1] == len(m.get("classes", conf))
    sums = conf.sum(axis=1)
    assert np.all(np.isclose(sums, 1.0) | np.isclose(sums, 0.0)), sums  # row-normalised
    assert np.all(conf >= 0)
    if "confusion_counts" in m:  # top-1 is the confusion trace over all tuples
        counts = np.asarray(m["confusion_counts"], dtype=float)
        assert counts.sum() == m["n_tuples"]
        assert m["top1"] == pytest.approx(np.trace(counts) / counts.sum(), abs=1e-6)
    if "per_class_tuples" in m:  # per-class accuracy is the diagonal of the classes scored
        classes = m["classes"]
        for name, n in m["per_class_tuples"].items():
            i = classes.index(name)
            assert n == np.asarray(m["confusion_counts"])[i].sum(), name
            assert m["per_class"][name] == pytest.approx(conf[i, i], abs=1e-6), name
