"""How the remote :class:`~tactus_memory.client.main.Client` turns the library's arguments into
the service's request parameters and bodies (a scope, a match rule, an array as ``.npy``)."""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.matching import Match
from tactus_memory.query import Scope
from tactus_memory.where import check_grip, check_near, check_regions


def scope_params(scope: Scope) -> dict[str, Any]:
    """A :class:`Scope` as the service's query parameters (``sense`` repeated)."""
    scope.bounds()  # after <= before, finite: the library's message, before any request
    params = {
        "session": scope.session,
        "sense": None if scope.senses is None else list(scope.senses),
        "source": scope.source,
        "after": scope.after,
        "before": scope.before,
        "frame": scope.frame,
        "force_min": scope.force_min,
        "force_max": scope.force_max,
        "area_min": scope.area_min,
        "grip": check_grip(scope.grip),
    }
    regions = check_regions(scope.regions)
    if regions is not None:  # the service's ``regions=thumb,index``
        params["regions"] = ",".join(regions)
    if scope.near is not None:  # the service's ``near=x,y,z,r``
        (x, y, z), r = check_near(scope.near)
        params["near"] = f"{x!r},{y!r},{z!r},{r!r}"
    return {k: v for k, v in params.items() if v is not None}


def match_params(match: Match) -> dict[str, Any]:
    if match.threshold is not None and not isinstance(match.threshold, (int, float)):
        raise InvalidInputError("over HTTP, threshold is one number for every sense")
    out: dict[str, Any] = {"relative": match.relative}
    if match.answer is not None:
        out["answer"] = match.answer
    if match.threshold is not None:
        out["threshold"] = match.threshold
    return out


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()
