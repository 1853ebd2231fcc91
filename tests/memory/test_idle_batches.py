"""Issue 36, defect 7: idle windows (no contact) in a batch are skipped and named, not a
refusal of the whole batch, from Python (``add_many``) and over HTTP (JSON and .npy batches
on a real uvicorn), with the real Tactus encoder, MiniLM and a real LanceDB store; one idle window
posted alone is skipped the same way (201, ``skipped: [0]``; issue 47), while ``Memory.add``
raises IdleWindowError."""

from __future__ import annotations

import httpx
import pytest

from benchmarks.serving import serve_app
from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.errors import IdleWindowError
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import npy_bytes, windows


@pytest.fixture(scope="module")
def encoder() -> TactusEncoder:
    return TactusEncoder()


def test_add_many_stores_the_rest_and_names_the_idle(tmp_path, encoder, minilm_space) -> None:
    memory = Memory.open(str(tmp_path / "mem"), space=minilm_space)
    memory.add_sense(encoder)
    batch = windows(200, idle={0, 57, 199})
    times = [float(i) for i in range(200)]
    ids = memory.add_many(
        "glove", "touch", list(batch), t=times, meta=[{"i": i} for i in range(200)]
    )
    assert ids.skipped == [(0, "idle"), (57, "idle"), (199, "idle")]
    assert len(ids) == 197 == len(memory)
    stored = {memory.get_item(i).t: memory.get_item(i).meta["i"] for i in ids}
    assert sorted(stored) == [t for t in times if t not in (0.0, 57.0, 199.0)]
    assert all(int(t) == i for t, i in stored.items())  # times and meta stay with their window
    all_idle = memory.add_many("glove", "touch", list(windows(3, idle={0, 1, 2})), t=[1, 2, 3])
    assert list(all_idle) == [] and [i for i, _ in all_idle.skipped] == [0, 1, 2]
    with pytest.raises(IdleWindowError, match="idle touch window"):
        memory.add("glove", "touch", batch[57], t=57.0)
    with pytest.raises(IdleWindowError):
        memory.add_many("glove", "touch", list(batch[:2]), t=[0, 1], skip_idle=False)
    assert len(memory) == 197


def test_http_batches_answer_201_with_skipped(tmp_path, encoder, minilm_space) -> None:
    memory = Memory.open(str(tmp_path / "mem"), space=minilm_space)
    memory.add_sense(encoder)
    batch = windows(6, idle={2, 5})
    with serve_app(create_app(Settings(), memory=memory)) as base:
        body = {"windows": batch.tolist(), "t": [float(i) for i in range(6)]}
        r = httpx.post(f"{base}/sessions/json/touch", json=body, timeout=120)
        assert r.status_code == 201, r.text
        out = r.json()
        assert out["count"] == 4 == len(out["ids"])
        assert out["skipped"] == [{"index": 2, "reason": "idle"}, {"index": 5, "reason": "idle"}]
        times = "&".join(f"t={i}" for i in range(6))
        headers = {"content-type": "application/x-npy"}
        r = httpx.post(f"{base}/sessions/npy/touch?{times}", content=npy_bytes(batch),
                       headers=headers, timeout=120)  # fmt: skip
        assert r.status_code == 201, r.text
        assert [s["index"] for s in r.json()["skipped"]] == [2, 5] and r.json()["count"] == 4
        one = {"frames": batch[2].tolist(), "t": 1.0}  # one window alone: skipped, as in a batch
        r = httpx.post(f"{base}/sessions/one/touch", json=one, timeout=60)
        assert r.status_code == 201 and r.json()["ids"] == [], r.text
        assert r.json()["skipped"] == [{"index": 0, "reason": "idle"}]
        r = httpx.post(f"{base}/sessions/one/touch", json={"frames": batch[0].tolist(), "t": 1.0},
                       timeout=60)  # fmt: skip
        assert r.status_code == 201 and r.json()["skipped"] == []
    assert {s.id: s.counts["touch"] for s in memory.sessions()} == {"json": 4, "npy": 4, "one": 1}
    assert sorted(i.t for i in memory.timeline("json")) == [0.0, 1.0, 3.0, 4.0]
