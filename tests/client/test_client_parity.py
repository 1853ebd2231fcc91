"""One scenario, two memories: ``Memory`` in process and ``Client`` against ``tactus serve`` on
a real uvicorn (real MiniLM, the shipped touch encoder, real LanceDB stores). Every answer,
and every error type, must be the same, so the two APIs cannot drift."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import Any

import anyio
import httpx
import numpy as np
import pytest
from mcp import Client as McpClient
from pydantic import BaseModel
from typer.testing import CliRunner

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.cli.app import app
from tactus_memory.client.errors import AuthenticationError, RemoteError
from tactus_memory.client.main import Client
from tactus_memory.contract import MemoryAPI
from tactus_memory.errors import (
    IdConflictError,
    InvalidIdError,
    InvalidInputError,
    NotFoundError,
    OverloadedError,
    UnknownSenseError,
)
from tactus_memory.identity import auth_headers
from tactus_memory.mcp.server import build_server
from tactus_memory.memory.main import Memory
from tactus_memory.search.captions import CAPTION_MIN_COS
from tactus_memory.touch.facets import caption
from tactus_memory.touch.regions import STAG_REGIONS
from tests.helpers import compare
from tests.helpers.servers import Server
from tests.helpers.service import window

NOTES = ["picked up the red mug", "put the mug on the shelf", "wiped the table with a sponge"]
TOKEN = "par1ty"


@pytest.fixture(scope="module")
def local(tmp_path_factory) -> Iterator[Memory]:
    from tactus_memory.adapters.touch import TactusEncoder

    with Memory.open(str(tmp_path_factory.mktemp("local") / "memory")) as memory:
        memory.add_sense(TactusEncoder())
        yield memory


@pytest.fixture(scope="module")
def remote(tmp_path_factory) -> Iterator[Client]:
    root = tmp_path_factory.mktemp("remote")
    server = Server(root / "memory", root / "server.log", "--token", TOKEN)
    try:
        with Client(server.base, token=TOKEN, timeout=120) as client:
            yield client
    finally:
        server.stop()


def normalise(value: Any, names: dict[str, str]) -> Any:
    """Models -> dicts, generated ids -> 'sense@t', floats rounded, stream ids dropped."""
    if isinstance(value, BaseModel):
        value = value.model_dump()
    if isinstance(value, dict):
        return {k: normalise(v, names) for k, v in value.items() if k not in ("created",)}
    if isinstance(value, (list, tuple)):
        return [normalise(v, names) for v in value]
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, str):
        return names.get(value, value)
    return value


#: two rounded floats are alike within this: one rounding step either way (a score computed in
#: two processes can fall on either side of a rounding boundary)
FLOAT_SLACK = 1.5e-3


def alike(a: Any, b: Any) -> bool:
    """``a == b`` for normalised answers, floats within :data:`FLOAT_SLACK`."""
    return compare.alike(a, b, FLOAT_SLACK)


def scenario(mem: Any) -> dict[str, Any]:
    """Writes, then every question; returns each answer (normalised) and each error's type."""
    out: dict[str, Any] = {}
    out["add"] = mem.add("kitchen", "text", NOTES[0], t=1.0, id="n1", meta={"by": "op"})
    out["add_many"] = mem.add_many("kitchen", "text", NOTES[1:], t=[10.0, 20.0], ids=["n2", "n3"])
    touch = mem.add_many(
        "kitchen", "touch", [window(seed=i) for i in range(3)], t=[2.0, 11.0, 21.0]
    )
    out["touch_ids"] = len(touch)
    mem.add_many("hall", "touch", [window(seed=7)], t=[5.0], meta=[{"glove": "left"}])
    mem.add_sense(VectorSense("motion", 384, encoder="imu-tcn", version="1.2"))
    motion = np.random.default_rng(3).standard_normal((2, 384))
    out["motion"] = mem.add_many("kitchen", "motion", motion, t=[3.0, 4.0], ids=["m1", "m2"])
    names = {i.id: f"{i.sense}@{i.t}" for s in ("kitchen", "hall") for i in mem.timeline(s)}

    def ask(key: str, fn: Callable[[], Any]) -> None:
        try:
            out[key] = normalise(fn(), names)
        except Exception as exc:  # noqa: BLE001  (the error's type is the answer)
            out[key] = f"raised {type(exc).__name__}"

    ask("search", lambda: mem.search("put the mug on the shelf", k=4))
    ask("search_text", lambda: mem.search("mug", k=2, senses=["text"], after=5.0))
    ask("search_group", lambda: mem.search("the red mug", k=2, group="moment"))
    ask("search_moments", lambda: mem.search_moments("wiped the table", k=2, session="kitchen"))
    # issue 22: grasps (the three kitchen touch windows are 9 s apart: three grasps)
    ask("search_grasp", lambda: mem.search("holding a mug", k=2, senses=["touch"], group="grasp"))
    ask("grasp_max", lambda: mem.search("a mug", k=1, group="grasp", pool="max", senses=["touch"]))
    ask("last_grasp", lambda: mem.last("holding a mug", senses=["touch"], group="grasp"))
    ask("count_grasp", lambda: mem.count("holding a mug", senses=["touch"], group="grasp"))
    ask("moments_grasp", lambda: mem.search_moments("a mug", k=1, group="grasp", pool="top"))
    ask("e_group", lambda: mem.count("holding a mug", group="moment"))
    ask("search_like", lambda: mem.search_like("touch", window(seed=1), k=2))
    ask("search_like_text", lambda: mem.search_like("text", "a sponge", k=1))
    ask("search_like_vector", lambda: mem.search_like("motion", vector=motion[1], k=1))
    ask("last", lambda: mem.last("the mug", senses=["text"]))
    ask("first", lambda: mem.first("the mug", senses=["text"], session="kitchen"))
    ask("none", lambda: mem.last("the mug", senses=["text"], after=100.0))
    ask("count", lambda: mem.count("mug", senses=["text"], merge_gap=1.0))
    ask("occurrences", lambda: mem.occurrences("table", session="kitchen", threshold=1.0))
    ask("before", lambda: mem.before("wiped the table", 15.0, senses=["text"]))
    ask("after", lambda: mem.after("picked up the red mug", 5.0, anchor_senses=["text"]))
    ask("timeline", lambda: mem.timeline("kitchen", senses=["touch"], after=1.5, limit=2))
    ask("sessions", mem.sessions)
    ask("session", lambda: mem.session("hall"))
    ask("session_ids", mem.session_ids)
    ask("senses", lambda: [(s.name, s.rows, s.live) for s in mem.sense_info()])
    mem.set_clock_offset("hall", "touch", 0.5)
    ask("clock", lambda: mem.clock_offsets("hall"))
    ask("hall_timeline", lambda: mem.timeline("hall"))
    ask("segment", lambda: mem.segment_episodes("kitchen"))
    ask("episodes", lambda: len(mem.episodes("kitchen")))
    # errors: the same library exception on both sides
    ask("e_session", lambda: mem.timeline("nowhere"))
    ask("e_k", lambda: mem.search("x", k=0))
    ask("e_range", lambda: mem.search("x", after=5.0, before=1.0))
    ask("e_sense", lambda: mem.search("x", senses=["smell"]))
    ask("e_conflict", lambda: mem.add("hall", "text", "other", t=1.0, id="n1"))
    ask("e_bad_id", lambda: mem.add("kitchen", "text", "x", t=1.0, id="../x"))
    ask("e_shape", lambda: mem.add("kitchen", "touch", np.zeros((8, 32, 31)) + 600, t=1.0))
    ask("e_nan", lambda: mem.add("kitchen", "touch", np.full((8, 32, 32), np.nan), t=1.0))
    ask("e_t_end", lambda: mem.add("kitchen", "text", "x", t=5.0, t_end=1.0))
    ask("e_dim", lambda: mem.add("kitchen", "motion", np.ones(3), t=1.0))
    ask("e_sense_dup", lambda: mem.add_sense(VectorSense("motion", 384, encoder="other")))
    ask("delete", lambda: mem.delete_session("hall"))
    ask("deleted", mem.session_ids)
    ask("e_delete", lambda: mem.delete_session("hall"))
    return out


@pytest.mark.slow
def test_memory_and_client_answer_alike(local, remote) -> None:
    want = scenario(local)
    got = scenario(remote)
    assert want["search"][0]["text"] == NOTES[1]  # the scenario asks real questions
    assert want["e_session"] == "raised NotFoundError" and want["e_k"] == "raised InvalidInputError"
    assert want["e_conflict"] == "raised IdConflictError"
    assert want["none"] is None and want["delete"] == 1
    assert want["search_like_vector"][0]["id"] == "motion@4.0"  # m2, named by sense@t
    assert [g["n"] for g in want["search_grasp"]] == [1, 1]  # windows 9 s apart: one each
    assert want["grasp_max"][0]["score"] == want["grasp_max"][0]["window_score"]
    assert want["e_group"] == "raised InvalidInputError"
    for key in want:
        assert alike(got[key], want[key]), (key, got[key], want[key])
    # both implement the one contract (checked statically by mypy in `make lint`; at run time
    # the Protocol sees that every method it names is there)
    assert isinstance(local, MemoryAPI) and isinstance(remote, MemoryAPI)
    assert not isinstance(object(), MemoryAPI)


@pytest.mark.slow
def test_stream_touch_and_auth_on_the_real_server(remote) -> None:
    with remote.stream_touch("glove", hz=30.0, t0=100.0, window=4, stride=4) as glove:
        for i in range(9):  # 2 full windows, 1 frame left over (not stored)
            glove.send(window(k=1, seed=i)[0])
        glove.send(np.zeros((32, 31)))  # a bad frame: an error message, the stream goes on
    assert len(glove.ids) == 2 and glove.windows_expected == 2
    assert [e["frame"] for e in glove.errors] == [9]
    items = remote.timeline("glove")
    assert [i.id for i in items] == glove.ids
    assert items[0].t == pytest.approx(100.0) and items[0].source == glove.stream_id
    with pytest.raises(AuthenticationError) as caught:
        Client(remote.url, token="wrong").sessions()
    assert caught.value.status == 401 and "bearer token" in caught.value.problem["detail"]
    with pytest.raises(RemoteError), Client(remote.url, token="wrong") as bad:
        bad.stream_touch("glove").__enter__()


# ----------------------------------------------------------------------------- retries
def answers(*responses: httpx.Response) -> tuple[httpx.MockTransport, list[httpx.Request]]:
    seen: list[httpx.Request] = []
    queue = list(responses)

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return queue.pop(0)

    return httpx.MockTransport(handler), seen


def problem(status: int, slug: str, retry: str | None = None) -> httpx.Response:
    body = {"type": f"urn:tactus-memory:problem:{slug}", "title": "t", "status": status}
    headers = {} if retry is None else {"Retry-After": retry}
    return httpx.Response(status, json={**body, "detail": "queue full"}, headers=headers)


def test_retries_honour_retry_after_and_are_bounded() -> None:
    ok = httpx.Response(200, json={"sessions": []})
    waits: list[float] = []
    transport, seen = answers(problem(503, "overloaded", "2"), problem(429, "http-429", "1"), ok)
    with Client("http://memory", transport=transport, sleep=waits.append) as c:
        assert c.sessions() == []
    assert waits == [2.0, 1.0] and len(seen) == 3
    # always overloaded: gives up after `retries` retries with the library's OverloadedError
    waits.clear()
    transport, seen = answers(*[problem(503, "overloaded", "1") for _ in range(3)])
    client = Client("http://m", transport=transport, retries=2, sleep=waits.append)
    with client as c, pytest.raises(OverloadedError) as caught:
        c.sessions()
    assert len(seen) == 3 and waits == [1.0, 1.0] and caught.value.retry_after == 1.0
    # a wait longer than max_retry_wait, or a 503 without Retry-After: no retry
    for response in (problem(503, "overloaded", "120"), problem(503, "read-only")):
        transport, seen = answers(response)
        client = Client("http://m", transport=transport, sleep=waits.append)
        with client as c, pytest.raises((OverloadedError, RemoteError)):
            c.sessions()
        assert len(seen) == 1


def test_problem_types_map_to_the_library_errors() -> None:
    for status, slug, cls in [
        (404, "not-found", NotFoundError),
        (404, "unknown-sense", UnknownSenseError),
        (422, "invalid-id", InvalidIdError),
        (409, "id-conflict", IdConflictError),
        (413, "http-413", RemoteError),
    ]:
        transport, _ = answers(problem(status, slug))
        with Client("http://m", transport=transport) as c, pytest.raises(cls):
            c.sessions()
    with Client("http://m", transport=answers()[0]) as c, pytest.raises(InvalidInputError):
        c.add("s", "text", "x", source="cam")  # checked before any request


def test_place_filter_goes_over_http() -> None:
    """``near``/``frame`` reach the service as ``near=x,y,z,r`` and ``frame`` (search and
    timeline), and a bad ``near`` is the library's error before any request."""
    hits = httpx.Response(200, json={"hits": []})
    timeline = httpx.Response(200, json={"items": []})
    transport, seen = answers(hits, timeline)
    with Client("http://memory", transport=transport) as c:
        assert c.search("mug", near=((1.0, 2.0, 3.0), 0.5), frame="map") == []
        assert c.timeline("s1", near=((0.0, 0.0, 0.0), 2.0)) == []
        with pytest.raises(InvalidInputError, match="near radius"):
            c.search("mug", near=((1.0, 2.0, 3.0), -1.0))
    assert seen[0].url.params["near"] == "1.0,2.0,3.0,0.5"
    assert seen[0].url.params["frame"] == "map"
    assert seen[1].url.params["near"] == "0.0,0.0,0.0,2.0"
    assert len(seen) == 2


# ----------------------------------------------------------------- touch facets (issue 50)
K = 8  # the shipped encoder's frames
GRIPS_SESSION = "grips"
#: windows: (id, regions pressed, raw level, start time); one 1 s window each, 5 s apart
WINDOWS = [
    ("pinch-light", ("thumb", "index"), 620, 10.0),
    ("pinch-firm", ("thumb", "index"), 700, 20.0),
    ("power", ("palm", "index", "middle", "ring"), 640, 30.0),
    ("press", ("palm",), 600, 40.0),
    ("tripod", ("thumb", "index", "middle"), 660, 50.0),
]
#: (filters and order, the ids they must give, in order where sorted)
CASES: list[tuple[dict[str, Any], list[str] | set[str]]] = [
    ({"grip": "pinch"}, {"pinch-light", "pinch-firm"}),
    ({"regions": "thumb,index"}, {"pinch-light", "pinch-firm", "tripod"}),
    ({"force_min": 58.0, "area_min": 0.03}, {"power", "tripod"}),  # forces ~52.6 55 64 47 60
    ({"sort": "-force"}, ["power", "tripod", "pinch-firm", "pinch-light", "press"]),
    ({"sort": "t", "grip": "pinch"}, ["pinch-light", "pinch-firm"]),
]


def glove_window(regions: tuple[str, ...], level: int, seed: int) -> np.ndarray:
    """(K, 32, 32) raw: the glove at rest (512), 6 taxels of each region at ``level``."""
    rng = np.random.default_rng(seed)
    w = np.full((K, 32, 32), 512, np.int16) + rng.integers(-2, 3, (K, 32, 32))
    for name in regions:
        rows, cols = np.nonzero(STAG_REGIONS.taxels(name))
        w[:, rows[:6], cols[:6]] = level
    return w.astype(np.int16)


def write(mem: Any) -> None:
    wins = [glove_window(r, lvl, i) for i, (_, r, lvl, _) in enumerate(WINDOWS)]
    t = [w[3] for w in WINDOWS]
    mem.add_many(
        GRIPS_SESSION, "touch", wins, t=t, t_end=[x + 1.0 for x in t], ids=[w[0] for w in WINDOWS]
    )


def _python(memory: Memory, kw: dict[str, Any]) -> list[str]:
    hits = memory.search("holding something", k=10, group="window", session=GRIPS_SESSION, **kw)
    return [h.id for h in hits]


def _http(url: str, kw: dict[str, Any]) -> list[str]:
    params = {"q": "holding something", "k": 10, "group": "window", "session": GRIPS_SESSION}
    r = httpx.get(url + "/search", params={**params, **kw}, headers=auth_headers(TOKEN))
    assert r.status_code == 200, r.text
    return [h["id"] for h in r.json()["hits"]]


def _client(remote: Client, kw: dict[str, Any]) -> list[str]:
    hits = remote.search("holding something", k=10, group="window", session=GRIPS_SESSION, **kw)
    return [h.id for h in hits]


def _cli(url: str, kw: dict[str, Any]) -> list[str]:
    args = ["search", "holding something", "--k", "10", "--windows", "--json"]
    args += ["--url", url, "--token", TOKEN, "--session", GRIPS_SESSION]
    for name, v in kw.items():
        args += [f"--{name.replace('_', '-')}", str(v)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    return [h["id"] for h in json.loads(res.output)]


def _mcp(memory: Memory, cases: list[tuple[str, dict[str, Any]]]) -> list[list[str]]:
    """Each (tool, arguments) case's ids, from the MCP ``search`` tool (its hits) or
    ``last``/``first``/``count`` (its occurrences' best ids), one session for them all."""

    async def main() -> list[list[str]]:
        out = []
        async with McpClient(build_server(memory)) as client:
            for tool, kw in cases:
                args = {"query": "holding something", "windows": True, **kw}
                args |= {"k": 10} if tool == "search" else {"threshold": BAR}
                r = await client.call_tool(tool, {**args, "session": GRIPS_SESSION})
                assert not r.is_error, r.content
                body = json.loads(r.content[0].text)
                out.append([h["id"] for h in body["hits"]] if tool == "search" else _bests(body))
        return out

    return anyio.run(main)


@pytest.mark.slow
def test_facet_filters_answer_alike_five_ways(local, remote) -> None:
    """Issue 50: touch facet filters and order asked five ways of the same windows: Python,
    HTTP, the CLI (``tactus search --url``), the Client and MCP (the SDK's client on the
    local memory in process); the same ids, in the same order where sorted."""
    write(local)
    write(remote)
    mcp = _mcp(local, [*(("search", kw) for kw, _ in CASES), *((r, kw) for r, kw, _ in WHEN)])
    for (kw, want), by_mcp in zip(CASES, mcp[: len(CASES)], strict=True):
        answers = {
            "python": _python(local, kw),
            "http": _http(remote.url, kw),
            "client": _client(remote, kw),
            "cli": _cli(remote.url, kw),
            "mcp": by_mcp,
        }
        if isinstance(want, list):  # an order: every way gives it
            assert all(a == want for a in answers.values()), (kw, answers)
        else:
            assert all(set(a) == want for a in answers.values()), (kw, answers)
    hit = local.search("holding", k=1, group="window", grip="tripod", session=GRIPS_SESSION)[0]
    assert hit.facets["grip"] == "tripod" and set(hit.facets["regions"]) == set(STAG_REGIONS.names)
    # captions (search.captions): words about the grip find the pinches above the power grasp,
    # whatever the encoder makes of the synthetic windows; the same over HTTP
    q = {"q": "a pinch with thumb and index", "k": 5, "session": GRIPS_SESSION}
    found = local.search(q["q"], k=5, session=GRIPS_SESSION)
    by_words = [h.id for h in found]
    assert set(by_words[:2]) == {"pinch-light", "pinch-firm"}, by_words
    assert found[0].cosine >= CAPTION_MIN_COS  # the caption's cosine answers, not the encoder's
    assert "power" not in by_words or by_words.index("power") > 1
    r = httpx.get(remote.url + "/search", params=q, headers=auth_headers(TOKEN))
    assert [h["id"] for h in r.json()["hits"]] == by_words
    _firmness_and_motion_in_words(local)
    when = _temporal(local, remote, mcp[len(CASES) :])
    for (route, kw, want), got in zip(WHEN, when, strict=True):
        assert all(a == want for a in got.values()), (route, kw, got)


def _firmness_and_motion_in_words(local: Memory) -> None:
    """Issue 50, caption rule 3: the firmness words follow the force over the glove's 548
    taxels (firm from 0.0994: power, tripod and pinch-firm; light under 0.094: press), not
    the peak taxel (pinch-light's peak, 0.8, made it "firm" under rule 2, press's "steady");
    "squeezing hard" finds the firm pinch by its caption. A grasp's own caption says its
    motion, so a long steady hold and a brief touch are found in words."""
    windows = local.search("x", k=5, group="window", session=GRIPS_SESSION)
    said = {h.id: caption(h.facets) for h in windows}  # a window's caption (touch.facets)
    assert said["pinch-firm"] == "squeezing hard, a firm pinch with thumb and index"
    assert said["pinch-light"] == "a steady pinch with thumb and index"
    assert said["press"] == "touching lightly, a light press with palm"
    firm = local.search("squeezing hard", k=1, group="window", session=GRIPS_SESSION)
    assert firm[0].id == "pinch-firm" and firm[0].cosine >= CAPTION_MIN_COS
    # a steady power grasp held 8 s (eight overlapping windows; 18 taxels at raw 590: force
    # ~53 of 548 taxels, steady) and a brief one (one 0.5 s window)
    held = [glove_window(("palm", "index", "middle"), 590, 20 + i) for i in range(9)]
    t = [float(i) for i in range(8)] + [60.0]
    t_end = [x + 1.0 for x in t[:8]] + [60.5]
    ids = local.add_many("hold", "touch", held, t=t, t_end=t_end)
    long = local.search("a long steady hold", k=2, senses=["touch"], session="hold")
    assert long[0].ids == ids[:8] and long[0].facets["caption"].startswith("a long steady hold")
    assert long[0].cosine >= CAPTION_MIN_COS  # its own caption answers
    brief = local.search("a brief touch", k=2, senses=["touch"], session="hold")
    assert brief[0].ids == ids[8:] and brief[0].facets["duration"] == 0.5


#: when-questions with a facet order (and filters): (route, arguments, the best ids of the
#: occurrences answered, in order). ``first``/``last`` are the ends of the order, ``count``
#: lists the occurrences in it; a bar of -100 lets every window match (the synthetic windows
#: clear no sense's own bar for these words; all score above the relative gate, 0.4 x the best)
WHEN: list[tuple[str, dict[str, Any], list[str]]] = [
    ("first", {"sort": "-force"}, ["power"]),
    ("last", {"sort": "-force"}, ["press"]),
    ("count", {"sort": "-force", "grip": "pinch"}, ["pinch-firm", "pinch-light"]),
]
BAR = -100.0


def _bests(body: Any) -> list[str]:
    """The best ids of a /first, /last or /count answer (a dict, as JSON or a model dump)."""
    if not body:
        return []
    if "moments" in body or "occurrences" in body:
        return [m["best"] for m in body.get("moments", body.get("occurrences"))]
    moment = body.get("moment") if "moment" in body or "found" in body else body
    return [] if moment is None else [moment["best"]]


def _temporal(local: Memory, remote: Client, mcp: list[list[str]]) -> list[dict]:
    """Each WHEN case asked five ways (as ``test_facet_filters_answer_alike_five_ways``; MCP's
    answers given), and /moments three ways: Python, HTTP, Client."""
    q, args = "holding something", {"session": GRIPS_SESSION, "threshold": BAR}
    out = []
    for (route, kw, _), by_mcp in zip(WHEN, mcp, strict=True):
        fn = getattr(local, route if route != "count" else "occurrences")
        remote_fn = getattr(remote, route if route != "count" else "occurrences")
        as_dict = lambda m: {} if m is None else m.model_dump()  # noqa: E731
        r = httpx.get(
            f"{remote.url}/{route}",
            params={"q": q, **args, "group": "window", **kw},
            headers=auth_headers(TOKEN),
        )
        assert r.status_code == 200, r.text
        cli = ["--url", remote.url, "--token", TOKEN, "--session", GRIPS_SESSION, "--json"]
        cli += ["--windows", "--threshold", str(BAR)]
        for name, v in kw.items():
            cli += [f"--{name.replace('_', '-')}", str(v)]
        res = CliRunner().invoke(app, [route, q, *cli])
        assert res.exit_code == 0, res.output
        out.append(
            {
                "python": _bests(as_dict(fn(q, group="window", **args, **kw))),
                "http": _bests(r.json()),
                "client": _bests(as_dict(remote_fn(q, group="window", **args, **kw))),
                "cli": _bests(json.loads(res.output) or {}),
                "mcp": by_mcp,
            }
        )
    kw = {"sort": "-force", "threshold": BAR, "group": "window", "session": GRIPS_SESSION}
    r = httpx.get(
        f"{remote.url}/moments", params={"q": q, "k": 2, **kw}, headers=auth_headers(TOKEN)
    )
    moments = {
        "python": [m.best for m in local.search_moments(q, 2, **kw)],
        "http": [m["best"] for m in r.json()["moments"]],
        "client": [m.best for m in remote.search_moments(q, 2, **kw)],
    }
    assert all(m == ["power", "tripod"] for m in moments.values()), moments
    return out
