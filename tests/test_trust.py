"""Issue 12 regressions (library + TestClient): each test reproduces one defect of the
adversarial run. The real-server ones (uvicorn, startup errors, access log) are in
tests/test_trust_server.py."""

from __future__ import annotations

import threading

import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import IdConflictError
from tactus_memory.service.app import create_app
from tactus_memory.service.settings import Settings
from tests.test_service import assert_problem
from tests.test_service_helpers import make_memory, window


@pytest.fixture
def memory(tmp_path):
    return make_memory(tmp_path / "mem")


@pytest.fixture
def client(memory):
    with TestClient(create_app(Settings(max_body_bytes=2 * 1024 * 1024), memory=memory)) as c:
        yield c


# --------------------------------------------------------------------- A: ids per session
def test_explicit_id_cannot_overwrite_another_sessions_row(memory):
    memory.add("alice", "text", "alice pin 4711", t=1.0, id="note-1")
    with pytest.raises(IdConflictError, match="note-1"):
        memory.add("bob", "text", "bob", t=2.0, id="note-1")
    with pytest.raises(IdConflictError):  # another sense, even in the same session
        memory.add("alice", "touch", window(), t=3.0, id="note-1")
    item = memory.get_item("note-1")
    assert (item.session, item.sense, item.text) == ("alice", "text", "alice pin 4711")
    assert [s.id for s in memory.sessions()] == ["alice"]
    # same session + same sense: still an idempotent upsert
    memory.add("alice", "text", "alice pin 4712", t=1.0, id="note-1")
    assert memory.get_item("note-1").text == "alice pin 4712"
    assert len(memory) == 1
    # a batch with one foreign id writes nothing at all
    with pytest.raises(IdConflictError):
        memory.add_many("bob", "text", ["x", "y"], t=[1, 2], ids=["fresh-1", "note-1"])
    assert len(memory) == 1


def test_racing_writers_cannot_both_claim_an_id(memory):
    """Two sessions write the same new id at once: exactly one wins, the other gets 409."""
    barrier = threading.Barrier(8)
    outcomes: list[str] = []

    def write(session: str) -> None:
        barrier.wait()
        try:
            memory.add(session, "text", f"note of {session}", t=1.0, id="shared")
            outcomes.append("ok:" + session)
        except IdConflictError:
            outcomes.append("conflict")

    threads = [threading.Thread(target=write, args=(f"s{i}",)) for i in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    winners = [o for o in outcomes if o.startswith("ok:")]
    assert len(winners) == 1, outcomes
    assert memory.get_item("shared").session == winners[0][3:]
    assert len(memory) == 1


def test_http_alice_bob_id_conflict_is_409(client):
    r = client.post("/sessions/alice/text", json={"text": "alice pin 4711", "t": 1, "id": "note-1"})
    assert r.status_code == 201, r.text
    r = client.post("/sessions/bob/text", json={"text": "bob", "t": 2, "id": "note-1"})
    body = assert_problem(r, 409, "note-1")
    assert body["type"].endswith("id-conflict")
    r = client.post(
        "/sessions/carol/touch", json={"frames": window(k=2).tolist(), "t": 3, "id": "note-1"}
    )
    assert_problem(r, 409, "note-1")
    assert client.get("/sessions/alice").status_code == 200
    assert client.get("/sessions/bob").status_code == 404
    counts = {s["name"]: s["rows"] for s in client.get("/senses").json()["senses"]}
    assert counts["text"] == 1 and counts["touch"] == 0, counts
    # the owner may still upsert it
    r = client.post("/sessions/alice/text", json={"text": "alice pin 4712", "t": 1, "id": "note-1"})
    assert r.status_code == 201, r.text
