"""Issue 36, defect 9: poses re-sent for times a session's trajectory already holds are
refused whole (PoseConflictError, HTTP 409 naming the times), never silently dropped so
that the trajectory mixes two batches; new times and another frame are stored. A real
LanceDB store and a real uvicorn server."""

from __future__ import annotations

import httpx
import pytest

from benchmarks.serving import serve_app
from tactus_memory.errors import PoseConflictError
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory


def test_resent_poses_are_refused_naming_the_times(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem", touch=False)
    memory.add_poses("walk", [0.0, 1.0, 2.0], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(PoseConflictError, match=r"t = 1, 2"):
        memory.add_poses("walk", [1.0, 2.0, 3.0], [[9, 9, 0], [9, 9, 0], [9, 9, 0]])
    with serve_app(create_app(Settings(), memory=memory)) as base:
        body = {"t": [2.0, 5.0], "position": [[7, 7, 0], [8, 8, 0]]}
        r = httpx.post(f"{base}/sessions/walk/poses", json=body, timeout=60)
        assert r.status_code == 409 and "t = 2" in r.json()["detail"], r.text
        assert r.json()["type"].endswith("pose-conflict")
        body = {"t": [3.0, 4.0], "position": [[3, 0, 0], [4, 0, 0]]}
        assert httpx.post(f"{base}/sessions/walk/poses", json=body, timeout=60).status_code == 201
        body["frame"] = "odom"  # another frame's trajectory: its own times
        assert httpx.post(f"{base}/sessions/walk/poses", json=body, timeout=60).status_code == 201
    stored = {tr.frame: list(tr.t) for tr in memory.places.poses.trajectories("walk")}
    assert stored == {"map": [0.0, 1.0, 2.0, 3.0, 4.0], "odom": [3.0, 4.0]}
