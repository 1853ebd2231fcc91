"""Issue 12 regressions (library + TestClient): each test reproduces one defect of the
adversarial run. The real-server ones (uvicorn, startup errors, access log) are in
tests/service/test_trust_server.py."""

from __future__ import annotations

import threading

import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import IdConflictError
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import assert_problem, window
from tests.helpers.threads import run_threads


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

    run_threads(write, [(f"s{i}",) for i in range(8)])
    winners = [o for o in outcomes if o.startswith("ok:")]
    assert len(winners) == 1, outcomes
    assert outcomes.count("conflict") == 7, outcomes
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


# --------------------------------------------------------------------- B: lone surrogates
@pytest.mark.parametrize(
    "meta_json", ['{"k": "\\udfff"}', '{"\\udfff": 1}', '{"k": ["a", {"x": "\\ud800"}]}']
)
def test_lone_surrogate_in_meta_is_a_clean_422(client, caplog, meta_json):
    body = '{"text": "a note", "t": 1, "meta": ' + meta_json + "}"
    with caplog.at_level("INFO"):
        r = client.post(
            "/sessions/s1/text", content=body, headers={"content-type": "application/json"}
        )
    assert_problem(r, 422, "meta", "surrogate")
    assert not [rec for rec in caplog.records if rec.exc_info], "no traceback for a 422"
    frames = window(k=2).tolist()
    touch = '{"frames": ' + str(frames) + ', "t": 1, "meta": ' + meta_json + "}"
    r = client.post(
        "/sessions/s1/touch", content=touch, headers={"content-type": "application/json"}
    )
    assert_problem(r, 422, "surrogate")


def test_library_refuses_lone_surrogate_in_meta(memory):
    from tactus_memory.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="surrogate"):
        memory.add("s1", "text", "x", t=1.0, meta={"k": "\udfff"})
    assert len(memory) == 0


# --------------------------------------------------------------------- E: health and ready
def _damage_items(memory) -> None:
    from pathlib import Path

    for f in (Path(memory.store.uri) / "items.lance" / "data").glob("*.lance"):
        f.write_bytes(f.read_bytes()[:10])


def test_health_is_503_with_the_reason_when_the_store_is_unreadable(client, memory):
    client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
    assert client.get("/health").status_code == 200
    assert client.get("/ready").json()["status"] == "ready"
    _damage_items(memory)
    r = client.get("/health")
    body = assert_problem(r, 503, "store", "damaged")
    assert memory.store.uri not in body["detail"]  # names the file, never where it lives
    assert_problem(client.get("/ready"), 503, "damaged")
    assert client.get("/live").json() == {"status": "ok"}  # liveness does not touch the store
    r = client.get("/search", params={"q": "red ball"})  # data routes: 503, not 500
    assert_problem(r, 503, "store")


def test_ready_waits_for_the_warm_up_and_probes_need_no_token(memory):
    app = create_app(Settings(token="s3cret"), memory=memory)
    c = TestClient(app)  # no lifespan yet: the text model is not warmed up
    r = c.get("/ready")
    assert_problem(r, 503, "starting")
    assert r.headers["retry-after"] == "1"
    with TestClient(app) as c:
        for path in ("/live", "/ready", "/health", "/openapi.json", "/docs", "/redoc", "/"):
            assert c.get(path).status_code == 200, path
        assert c.get("/sessions").status_code == 401


# --------------------------------------------------------------------- F: read-only (flag)
def test_read_only_store_refuses_writes_and_serves_reads(client):
    client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
    client.app.state.tactus.read_only = True
    assert client.get("/health").json()["read_only"] is True
    assert client.get("/search", params={"q": "red ball"}).status_code == 200
    r = client.post("/search/like", json={"text": "red ball"})
    assert r.status_code != 503, r.text
    r = client.post("/search/like/image", files={"file": ("x.png", b"not a png", "image/png")})
    assert r.status_code != 503, r.text  # a read-only POST: answered by the route, not refused
    assert_problem(client.post("/sessions/s1/text", json={"text": "x", "t": 2}), 503, "read-only")
    assert_problem(client.delete("/sessions/s1"), 503, "read-only")
    assert_problem(
        client.put("/sessions/s1/clock", json={"sense": "touch", "offset": 1.0}), 503, "read-only"
    )
    with client.websocket_connect("/sessions/s1/touch/stream") as ws:
        msg = ws.receive_json()
    assert msg["type"] == "error" and "read-only" in msg["error"]["detail"]


# --------------------------------------------------------------------- G: empty token
@pytest.mark.parametrize("token", ["", "   "])
def test_empty_token_is_refused(token):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="token is empty"):
        Settings(token=token)


# --------------------------------------------------------------------- H: redaction
def test_redact_hides_query_tokens_and_bearer_credentials():
    import logging

    from tactus_memory.service.logs import RedactSecrets, redact

    line = redact('127.0.0.1:5 - "GET /sessions/s/touch/stream?window=8&token=s3cr%2Bet&x=1"')
    assert "s3cr" not in line and "token=***&x=1" in line
    assert redact("Authorization: Bearer abc.def") == "Authorization: Bearer ***"
    rec = logging.LogRecord(
        "uvicorn.access", 20, "", 0, '%s - "%s %s"', ("1.2.3.4", "GET", "/x?token=abc"), None
    )
    assert RedactSecrets().filter(rec) and "abc" not in rec.getMessage()


# --------------------------------------------------------------------- I: strictness
@pytest.mark.parametrize(
    ("path", "body"),
    [
        ("/sessions/s1/text", {"text": "x", "t": False}),
        ("/sessions/s1/text", {"text": "x", "t": 1, "t_end": True}),
        ("/sessions/s1/clock", {"sense": "touch", "offset": False}),
        ("/sessions/s1/touch", {"frames": [[[True] * 32] * 32], "t": 1}),
    ],
)
def test_booleans_are_not_numbers(client, path, body):
    method = client.put if path.endswith("clock") else client.post
    assert_problem(method(path, json=body), 422)


def test_clock_offset_is_bounded_so_t_aligned_stays_finite(client, memory):
    from tactus_memory.errors import InvalidInputError

    client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
    r = client.put("/sessions/s1/clock", json={"sense": "text", "offset": 1e308})
    assert_problem(r, 422, "offset")
    with pytest.raises(InvalidInputError, match="offset"):
        memory.set_clock_offset("s1", "text", 1e308)
    r = client.put("/sessions/s1/clock", json={"sense": "text", "offset": 1e9})
    assert r.status_code == 200, r.text
    items = client.get("/sessions/s1/timeline").json()["items"]
    assert items[0]["t_aligned"] == 1e9 + 1.0


def test_binary_websocket_garbage_gets_a_clear_error_without_pickle(client):
    import io
    import os

    import numpy as np

    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with client.websocket_connect("/sessions/s1/touch/stream") as ws:
        assert ws.receive_json()["type"] == "ready"
        for payload in (os.urandom(200), b"\x93NUMPY" + os.urandom(100), buf.getvalue()):
            ws.send_bytes(payload)
            msg = ws.receive_json()
            assert msg["type"] == "error", msg
            detail = msg["error"]["detail"]
            assert "pickle" not in detail.lower() and ".npy" in detail, detail


def test_options_and_405_name_every_method_of_the_path(client):
    r = client.options("/sessions/s1")
    assert r.status_code in (200, 204), r.text
    allow = {m.strip() for m in r.headers["allow"].split(",")}
    assert {"GET", "DELETE"} <= allow and "POST" not in allow
    r = client.options("/sessions/s1/clock")
    assert {"GET", "PUT"} <= {m.strip() for m in r.headers["allow"].split(",")}
    r = client.patch("/sessions/s1/clock", json={})
    assert_problem(r, 405)
    assert {"GET", "PUT"} <= {m.strip() for m in r.headers["allow"].split(",")}
    assert client.options("/no/such/route").status_code == 404


def test_deleting_a_session_removes_its_clock_offsets(client):
    """schemathesis ST301: after DELETE /sessions/{id}, its clock offsets were still served."""
    client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
    r = client.put(
        "/sessions/s1/clock", json={"sense": "touch", "source": "glove-l", "offset": 2.5}
    )
    assert r.json()["offsets"], r.text
    assert client.delete("/sessions/s1").status_code == 200
    assert_problem(client.get("/sessions/s1/clock"), 404)  # deleted: gone, offsets too
    r = client.put("/sessions/s9/clock", json={"sense": "touch", "offset": 1.0})
    assert client.get("/sessions/s9/clock").json()["offsets"], r.text  # offsets alone: exists


# --------------------------------------------------------------------- issue 36: meta depth
def _nested(levels: int) -> dict:
    meta: dict = {}
    inner = meta
    for _ in range(levels - 1):
        inner["a"] = {}
        inner = inner["a"]
    return meta


def test_meta_nested_too_deep_is_refused_naming_the_limit(client, memory):
    from tactus_memory.errors import InvalidInputError
    from tactus_memory.limits import MAX_META_DEPTH

    memory.add("s1", "text", "x", t=1.0, meta=_nested(MAX_META_DEPTH))  # at the limit: stored
    for levels in (MAX_META_DEPTH + 1, 250, 5000):
        with pytest.raises(InvalidInputError, match="nests deeper than"):
            memory.add("s1", "text", "x", t=1.0, meta=_nested(levels))
    deep_list: list = []
    for _ in range(300):
        deep_list = [deep_list]
    with pytest.raises(InvalidInputError, match="nests deeper than"):
        memory.add("s1", "text", "x", t=1.0, meta={"k": deep_list})
    assert len(memory) == 1
    body = {"text": "a note", "t": 1, "meta": _nested(250)}
    assert_problem(client.post("/sessions/s1/text", json=body), 422, "nests deeper")
