"""The measured figures shipped for a space's own senses (package data beside this module).

* ``calibration-priors.json``: the prior score calibration of a space's text sense
  (``search/scoring.py``, "A prior for a young sense"), keyed by space name then modality;
  written by ``benchmarks/text_prior.py`` (the probe null against a documented,
  reproducible corpus of robot-log notes, ``benchmarks/text_notes.py``).
* ``match-precision.json``: how often a text match is right at the text bar
  (``GET /senses``' ``precision_at_bar``), keyed likewise; written by
  ``benchmarks/text_precision.py``.

A space without a row (a space no figure was measured for, e.g. a test's fake space or
Qwen3-VL, whose weights are not shipped) gets None: its text sense uses its own estimate alone
and reports no precision.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

#: the prior score calibrations of the shipped spaces' senses, by space name then modality
CALIBRATION_PRIORS = "calibration-priors.json"
#: the measured precision at the match bar of the shipped spaces' senses, likewise
MATCH_PRECISION = "match-precision.json"


def figures_path(name: str) -> Path:
    """The path of one shipped figures file (may not exist)."""
    return Path(str(resources.files("tactus_memory.spaces") / name))


def _row(name: str, key: str, space: str, modality: str) -> dict[str, Any] | None:
    path = figures_path(name)
    if not path.is_file():
        return None
    row = json.loads(path.read_text()).get(key, {}).get(space, {}).get(modality)
    return None if row is None else dict(row)


def calibration_prior(space: str, modality: str) -> dict[str, float] | None:
    """``{"mu", "sigma"}`` of the prior shipped for ``modality`` in ``space`` (None: none)."""
    row = _row(CALIBRATION_PRIORS, "priors", space, modality)
    return None if row is None else {"mu": float(row["mu"]), "sigma": float(row["sigma"])}


def match_precision(space: str, modality: str) -> dict[str, Any] | None:
    """The measured precision at the match bar of ``modality`` in ``space`` (None: none)."""
    return _row(MATCH_PRECISION, "precision_at_bar", space, modality)
