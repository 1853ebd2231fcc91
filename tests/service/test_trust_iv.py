"""Issue 48 ("Trust, part IV") on the real path, a real uvicorn on 127.0.0.1 over a real
LanceDB store: teachings do not outlive retention or the deletion of their windows (defect
4), names a person reads refuse Unicode format characters (defect 9), and ``GET /at``'s
schema offers what the route takes (defect 10). The time rule (defect 1) is
tests/service/test_time_rule.py; the MCP defects are tests/mcp/test_mcp_times.py."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from benchmarks.serving import serve_app
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.retention import DAY_S
from tests.helpers.fakes import HashingSpace
from tests.helpers.service import DIM, StandInTouch, window


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[tuple[str, Memory]]:
    """Sessions old-1 (expires after 30 days) and keep (kept), two touch windows each."""
    rules = [{"session": "keep", "retain_days": None}]
    cfg = Settings(retain_days=30, retention=rules).maintenance()
    memory = Memory.open(
        str(tmp_path_factory.mktemp("trust-iv") / "mem"),
        space=HashingSpace(dim=DIM),
        maintenance=cfg,
        background=False,
    )
    memory.add_sense(StandInTouch(DIM))
    for session in ("old-1", "keep"):
        memory.add_many(session, "touch", [window(seed=1), window(seed=2)], t=[1.0, 2.0])
    with serve_app(create_app(Settings(), memory=memory)) as base:
        yield base, memory


def _labels(c: httpx.Client) -> list[tuple[str, str]]:
    return sorted((t["label"], t["session"]) for t in c.get("/labels").json()["labels"])


def _sense_labels(c: httpx.Client) -> list[str]:
    senses = {s["name"]: s for s in c.get("/senses").json()["senses"]}
    return sorted(senses["touch"]["taught"])


def test_expiry_and_deletion_drop_the_teachings_of_their_windows(served) -> None:
    base, memory = served
    with httpx.Client(base_url=base, timeout=120) as c:
        for session, label in (("old-1", "drill"), ("keep", "mug"), ("keep", "cup")):
            r = c.post(f"/sessions/{session}/labels", json={"label": label, "t": 0.5})
            assert r.status_code == 201, r.text
        assert _labels(c) == [("cup", "keep"), ("drill", "old-1"), ("mug", "keep")]
        assert _sense_labels(c) == ["cup", "drill", "mug"]
        # day 31: old-1 expires; its teaching goes with it, as a session delete takes it
        rep = memory.store.retention.run(time.time() + 31 * DAY_S, force=True)
        assert rep.expired == 2
        assert _labels(c) == [("cup", "keep"), ("mug", "keep")]
        assert _sense_labels(c) == ["cup", "mug"]
        assert c.delete("/sessions/old-1").status_code == 404  # nothing left to delete
        # the windows of keep deleted by id: its teachings have nothing left to point at
        ids = [i.id for i in memory.timeline("keep")]
        assert memory.delete(ids) == 2
        assert _labels(c) == [] and _sense_labels(c) == []


@pytest.mark.parametrize(
    "name", ["dri\u202ell\u200b", "mug\u200d", "\ufeffcup", "cup\u2066x\u2069", "tag\U000e0041"]
)
def test_format_characters_are_refused_in_names_a_person_reads(served, name: str) -> None:
    base, _ = served
    with httpx.Client(base_url=base, timeout=120) as c:
        r = c.post("/sessions/keep/labels", json={"label": name})
        assert r.status_code == 422 and "format characters" in r.text, r.text
        r = c.post("/senses", json={"name": "imu", "dim": DIM, "encoder": name})
        assert r.status_code == 422, r.text
        r = c.post("/senses", json={"name": "imu", "dim": DIM, "version": name})
        assert r.status_code == 422, r.text
        r = c.post(f"/sessions/{name}/text", json={"text": "x", "t": 1.0})
        assert r.status_code in (404, 422), r.text  # ids are [A-Za-z0-9._:-]
        assert all(name not in lab for lab, _ in _labels(c))


def test_at_schema_offers_what_the_route_takes(served) -> None:
    base, _ = served
    with httpx.Client(base_url=base, timeout=120) as c:
        spec = c.get("/openapi.json").json()
        params = {p["name"]: p for p in spec["paths"]["/at"]["get"]["parameters"]}
        assert "near" not in params  # the route refuses it: the schema does not offer it
        # every parameter the schema offers is taken (200 with each given)
        values: dict[str, Any] = {"x": 0, "y": 0, "z": 0, "r": 1, "session": "keep",
                                  "sense": "touch", "source": "", "after": 0, "before": 9,
                                  "frame": "map"}  # fmt: skip
        assert set(values) == set(params), set(params) ^ set(values)
        r = c.get("/at", params=values)
        assert r.status_code == 200, r.text
        r = c.get("/at", params={"x": 0, "y": 0, "z": 0, "r": 1, "near": "0,0,0,1"})
        assert r.status_code == 422 and "drop near" in r.text, r.text
