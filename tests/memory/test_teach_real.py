"""Objects you teach, on the real path: real MiniLM, the shipped touch encoder, real LanceDB,
windows cut from the real STAG blindfolded recordings by the stream windowing; the HTTP
route on a real uvicorn ``tactus serve``, the Client, the CLI and the MCP tool."""

from __future__ import annotations

import json
from collections.abc import Iterator

import anyio
import httpx
import numpy as np
import pytest
from mcp import Client as McpClient
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.client.main import Client
from tactus_memory.errors import InvalidInputError, NotFoundError, UnknownSenseError
from tactus_memory.mcp.server import build_server
from tactus_memory.memory.main import Memory
from tactus_memory.search import teaching
from tactus_memory.touch.targets import centre, class_phrases
from tactus_memory.training import stream_eval
from tactus_memory.training.data import load_stag
from tests.helpers.servers import Server

pytestmark = pytest.mark.slow

QUERY = "when was I holding the drill?"
GATE = 3  # the opt-in agreement gate (Teachings.agree_top) checked beside the default
TOKEN = "t3ach"


@pytest.fixture(scope="module")
def encoder() -> TactusEncoder:
    return TactusEncoder()


@pytest.fixture(scope="module")
def streams(stag_subset):
    """Two recordings of different objects, each its own stream (session)."""
    data = load_stag(stag_subset("blindfolded_lite_train"))
    first: dict[int, int] = {}
    for r in np.unique(data.recording_id):
        obj = int(data.object_id[data.recording_id == r][0])
        first.setdefault(obj, int(r))
    a, b = list(first.values())[:2]
    return stream_eval.build_stream(data, [a]), stream_eval.build_stream(data, [b])


def _store(mem, session: str, stream) -> list[str]:
    keep = np.flatnonzero(~stream.idle)
    return mem.add_many(
        session, "touch", list(stream.frames[keep]),
        t=stream.t[keep].tolist(), t_end=stream.t_end[keep].tolist(),
    )  # fmt: skip


@pytest.fixture
def memory(tmp_path, minilm_space, encoder, streams) -> Iterator[Memory]:
    with Memory.open(str(tmp_path / "m"), space=minilm_space, background=False) as mem:
        mem.add_sense(encoder)
        _store(mem, "lesson", streams[0])
        _store(mem, "day", streams[1])
        yield mem


def _span(stream) -> tuple[float, float]:
    keep = ~stream.idle
    return float(stream.t[keep].min()), float(stream.t_end[keep].max())


def test_teaching_steers_queries_by_label_and_prototype(memory, minilm_space, encoder, streams):
    # per window (group="window"): each hit's cosine is its own window's, checked exactly
    before = memory.search(QUERY, k=5, senses=["touch"], session="day", group="window")
    q = minilm_space.embed_texts([QUERY], query=True)
    plain = encoder.query_transform(q)[0]
    assert before[0].cosine == pytest.approx(
        float(memory.get_item(before[0].id, vector=True).vector @ plain), abs=1e-4
    )  # untaught: the drill is nobody's class, the query goes as it is

    t0, t1 = _span(streams[0])
    got = memory.teach("drill", session="lesson", after=t0, before=t1)
    assert got.windows == int((~streams[0].idle).sum()) and got.label == "drill"
    assert [t.label for t in memory.taught()] == ["drill"]
    info = {s.name: s for s in memory.sense_info()}
    assert info["touch"].taught == ["drill"] and len(info["touch"].classes) == 27
    assert info["text"].taught == [] and info["text"].classes == []

    # the rule: normalize(W_TEXT * centred label phrase + W_PROTO * mean taught embedding),
    # with the opt-in gate the words count only when the label's phrase is among the GATE
    # targets (trained classes and the label, centred) nearest the prototype
    lesson = [memory.get_item(h.id, vector=True).vector for h in
              memory.timeline("lesson", senses=["touch"], limit=1000)]  # fmt: skip
    proto = np.mean(lesson, axis=0)
    proto /= np.linalg.norm(proto)
    phrase = minilm_space.embed_texts(class_phrases("drill"), query=False).mean(axis=0)
    phrase /= np.linalg.norm(phrase)
    target = centre(phrase, encoder.query_centroid)
    every = centre(np.vstack([encoder.class_targets()[1], phrase]), encoder.query_centroid)
    agrees = int((every @ proto > every[-1] @ proto).sum()) < GATE
    for agree_top, w_text in ((GATE, agrees), (None, 1.0)):
        memory.teachings.agree_top = agree_top  # None: the words always count (the default)
        steer = w_text * teaching.W_TEXT * target + teaching.W_PROTO * proto
        steer /= np.linalg.norm(steer)
        after = memory.search(QUERY, k=5, senses=["touch"], session="day", group="window")
        for h in after:
            v = memory.get_item(h.id, vector=True).vector
            assert h.cosine == pytest.approx(float(v @ steer), abs=1e-4), agree_top
    # a label that is a trained class: its words always count (the class's own target)
    memory.teachings.agree_top = GATE
    memory.teach("mug", session="lesson", after=t0, before=t1)
    classes, raw = encoder.class_targets()
    steer = teaching.W_TEXT * centre(raw[list(classes).index("mug")], encoder.query_centroid)
    steer = steer + teaching.W_PROTO * proto
    steer /= np.linalg.norm(steer)
    ask = "when was I holding the mug?"
    for h in memory.search(ask, k=3, senses=["touch"], session="day", group="window"):
        v = memory.get_item(h.id, vector=True).vector
        assert h.cosine == pytest.approx(float(v @ steer), abs=1e-4)
    memory.forget("mug")
    memory.teachings.agree_top = teaching.TEXT_AGREE_TOP
    # the taught grasp itself is what the label finds first
    top = memory.search(QUERY, k=1, senses=["touch"], group="window")[0]
    assert top.session == "lesson" and t0 <= top.t <= t1
    # a query nearest an untaught class is ranked as before
    mug = "a hand holding a mug"
    hits = memory.search(mug, k=3, senses=["touch"], group="window")
    plain_mug = encoder.query_transform(minilm_space.embed_texts([mug], query=True))[0]
    for h in hits:
        v = memory.get_item(h.id, vector=True).vector
        assert h.cosine == pytest.approx(float(v @ plain_mug), abs=1e-4)
    assert memory.last(QUERY, session="lesson") is not None


def test_deleting_the_session_removes_the_teaching(memory, streams):
    memory.teach("drill", session="lesson")
    memory.teach("Drill", session="lesson")  # same label, case-insensitively
    assert {s.name: s.taught for s in memory.sense_info()}["touch"] == ["drill"]
    memory.delete_session("day")
    assert len(memory.taught()) == 2
    memory.delete_session("lesson")
    assert memory.taught() == []
    assert memory.forget("drill") == 0


def test_teaching_is_per_tenant_and_forgettable(tmp_path, minilm_space, encoder, streams):
    path = str(tmp_path / "m")
    with Memory.open(path, space=minilm_space, background=False) as mine:
        mine.add_sense(encoder)
        _store(mine, "lesson", streams[0])
        mine.teach("drill", session="lesson")
    with Memory.open(path, space=minilm_space, background=False, tenant="other") as other:
        other.add_sense(encoder)
        _store(other, "lesson", streams[0])
        assert other.taught() == []  # the other tenant's memory has its own teachings
    with Memory.open(path, space=minilm_space, background=False) as mine:  # persisted
        assert [t.label for t in mine.taught("touch")] == ["drill"]
        assert mine.forget("DRILL") == 1 and mine.taught() == []


def test_bad_teaching_is_a_typed_error(memory):
    with pytest.raises(InvalidInputError, match="label"):
        memory.teach("  ", session="lesson")
    with pytest.raises(InvalidInputError, match="label"):
        memory.teach("x" * 65, session="lesson")
    with pytest.raises(NotFoundError, match="nothing to teach"):
        memory.teach("drill", session="lesson", after=1e6, before=2e6)
    with pytest.raises(NotFoundError, match="nothing to teach"):
        memory.teach("drill", session="nobody")
    with pytest.raises(InvalidInputError, match="later than"):
        memory.teach("drill", session="lesson", after=5.0, before=1.0)
    with pytest.raises(UnknownSenseError, match="smell"):
        memory.teach("drill", session="lesson", sense="smell")
    memory.add("lesson", "text", "a note", t=1.0)
    with pytest.raises(InvalidInputError, match="not text"):
        memory.teach("drill", session="lesson", sense="text")
    with pytest.raises(InvalidInputError, match="exactly one"):
        memory.forget()
    assert memory.taught() == []


def test_mcp_and_cli_teach(tmp_path, memory):
    async def main() -> None:
        async with McpClient(build_server(memory, allow_writes=True)) as client:
            tools = {t.name for t in (await client.list_tools()).tools}
            assert "teach" in tools
            r = await client.call_tool("teach", {"session": "lesson", "label": "drill"})
            assert not r.is_error and json.loads(r.content[0].text)["label"] == "drill"
            r = await client.call_tool("teach", {"session": "nobody", "label": "drill"})
            assert r.is_error and "nothing to teach" in r.content[0].text

    anyio.run(main)

    async def read_only() -> None:
        async with McpClient(build_server(memory)) as client:
            assert "teach" not in {t.name for t in (await client.list_tools()).tools}

    anyio.run(read_only)
    assert [t.label for t in memory.taught()] == ["drill"]
    memory.close()

    from tactus_memory.cli import app

    runner = CliRunner()
    data = str(tmp_path / "m")
    r = runner.invoke(app, ["teach", "kettle", "--session", "day", "--data", data, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["label"] == "kettle"
    r = runner.invoke(app, ["teach", "kettle", "--session", "nobody", "--data", data])
    assert r.exit_code != 0 and "nothing to teach" in r.output


def test_labels_over_http(tmp_path, streams):
    server = Server(tmp_path / "memory", tmp_path / "server.log", "--token", TOKEN)
    try:
        with Client(server.base, token=TOKEN, timeout=120) as client:
            keep = np.flatnonzero(~streams[0].idle)[:12]
            client.add_many(
                "lesson", "touch", list(streams[0].frames[keep]),
                t=streams[0].t[keep].tolist(), t_end=streams[0].t_end[keep].tolist(),
            )  # fmt: skip
            got = client.teach("drill", session="lesson")
            assert got.windows == len(keep) > 1 and got.sense == "touch"
            senses = {s.name: s for s in client.sense_info()}
            assert senses["touch"].taught == ["drill"] and "mug" in senses["touch"].classes
            top = client.search(QUERY, k=1, senses=["touch"])[0]
            assert top.session == "lesson"
            with pytest.raises(NotFoundError, match="nothing to teach"):
                client.teach("drill", session="lesson", after=1e6, before=2e6)
            auth = {"Authorization": f"Bearer {TOKEN}"}
            with httpx.Client(base_url=server.base, headers=auth, timeout=60) as c:
                r = c.post("/sessions/lesson/labels", json={"label": "", "t": 0})
                assert r.status_code == 422 and "label" in r.text
                r = c.post("/sessions/lesson/labels", json={"label": "drill", "sense": "smell"})
                assert r.status_code == 404 and "smell" in r.text
                r = c.post("/sessions/lesson/labels", json={"label": "drill", "t": "soon"})
                assert r.status_code == 422
                r = c.get("/labels")
                assert [t["label"] for t in r.json()["labels"]] == ["drill"]
                assert c.delete("/labels/" + "0" * 32).status_code == 404
            anonymous = httpx.post(server.base + "/sessions/lesson/labels", json={"label": "x"})
            assert anonymous.status_code == 401
            assert client.forget("drill") == 1 and client.taught() == []
            client.teach("drill", session="lesson")
            assert client.delete_session("lesson") == len(keep) and client.taught() == []
    finally:
        server.stop()
