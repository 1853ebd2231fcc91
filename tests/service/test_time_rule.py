"""Issue 48, the time rule (tactus_memory/times.py) on every door that takes a time.

A real uvicorn on 127.0.0.1 over a store with a touch sense: every route, query parameter,
form field and WebSocket message that carries a time is sent the edge values (0, -0.0, a
subnormal, 1e9, a ROS stamp in nanoseconds, 1e308, inf, nan, booleans, a string); each must
be refused with a 4xx naming the problem or stored, and then every read (search in each
grouping, the temporal questions, the timeline, the sessions, the labels) must answer. The
reads run under a client timeout as a liveness bound (READ_LIVENESS_S): before the rule, one
touch window at t=1e18 made GET /search never return (find_grasps re-read a span that
t +- 30 s could not widen), so the timeout is the failure, not a speed target. The OpenAPI
schema is checked to advertise the same rule on every time it names, and this test to cover
every one of them."""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from benchmarks.serving import serve_app
from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_SECONDS
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.times import check_time
from tests.helpers.service import DIM, make_memory, npy_bytes, window

#: what every time-taking door is sent (the issue's list): JSON-able ones as JSON values,
#: inf and nan as the non-standard tokens Python's json writes (Infinity, NaN)
EDGES: list[Any] = [0, -0.0, 5e-324, 1e9, 1.7e18, 1e308, math.inf, -math.inf, math.nan]
EDGES += [True, False, "3"]
#: values the rule keeps (|t| <= MAX_SECONDS, finite, a number)
KEPT = {0, 5e-324, 1e9}
#: a liveness bound on each read: a read that does not answer in this long has hung (the
#: issue's freeze never answered at all); not a speed target (answers take milliseconds)
READ_LIVENESS_S = 30.0
S = "edge"
#: the doors whose values travel as text (a query string, a form): "3" there is 3 seconds
TEXT_DOORS = ("get", "timeline", "touch.npy", "windows.npy", "image.t", "like.image")

#: every time a client can send over HTTP: (method, path, where) -> covered below
TIME_FIELDS = {
    ("post", "/sessions/{session}/text"): {"t", "t_end"},
    ("post", "/sessions/{session}/vectors"): {"t", "t_end"},
    ("post", "/sessions/{session}/touch"): {"t", "t_end"},
    ("post", "/sessions/{session}/senses/{sense}/windows"): {"t", "t_end"},
    ("post", "/sessions/{session}/labels"): {"t", "t_end"},
    ("post", "/search/like"): {"after", "before"},
    ("post", "/search/like/image"): {"after", "before"},
    **{
        ("get", p): {"after", "before"}
        for p in (
            "/search",
            "/last",
            "/first",
            "/count",
            "/before",
            "/after",
            "/moments",
            "/where",
            "/at",
            "/sessions/{session}/timeline",
        )  # fmt: skip
    },
}


def _dumps(body: Any) -> bytes:
    return json.dumps(body).encode()  # NaN / Infinity tokens for nan / inf: refused


def _q(v: Any) -> str:
    return str(v)  # a query string carries text: "True" is not a number, "3" is 3 s


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Iterator[str]:
    memory = make_memory(tmp_path_factory.mktemp("times") / "mem")
    memory.add(S, "touch", window(seed=3), t=2.0, t_end=2.5)  # a grasp to read around
    app = create_app(Settings(max_body_bytes=4 * 1024 * 1024), memory=memory)
    with serve_app(app) as url:
        r = httpx.post(url + "/senses", json={"name": "motion", "dim": DIM}, timeout=60)
        assert r.status_code in (200, 201), r.text
        yield url


def _writes(c: httpx.Client, v: Any) -> dict[str, httpx.Response]:
    """Every HTTP door that takes a time, sent ``v``; name -> response."""
    js = {"content-type": "application/json"}
    frames = window(seed=7).tolist()
    vec = [1.0] + [0.0] * (DIM - 1)
    out = {
        "text.t": c.post(
            f"/sessions/{S}/text", content=_dumps({"text": "a mug", "t": v}), headers=js
        ),
        "text.t_end": c.post(
            f"/sessions/{S}/text", content=_dumps({"text": "a cup", "t": 0, "t_end": v}), headers=js
        ),
        "touch.json": c.post(
            f"/sessions/{S}/touch", content=_dumps({"frames": frames, "t": v}), headers=js
        ),
        "touch.batch": c.post(
            f"/sessions/{S}/touch", content=_dumps({"windows": [frames], "t": [v]}), headers=js
        ),
        "touch.npy": c.post(
            f"/sessions/{S}/touch",
            params={"t": _q(v)},
            content=npy_bytes(window(seed=8)[None]),
            headers={"content-type": "application/x-npy"},
        ),
        "windows.json": c.post(
            f"/sessions/{S}/senses/touch/windows",
            content=_dumps({"frames": frames, "t": v}),
            headers=js,
        ),
        "windows.npy": c.post(
            f"/sessions/{S}/senses/touch/windows",
            params={"t": _q(v)},
            content=npy_bytes(window(seed=9)[None]),
            headers={"content-type": "application/x-npy"},
        ),
        "vectors": c.post(
            f"/sessions/{S}/vectors",
            content=_dumps({"sense": "motion", "vectors": [vec], "t": [v]}),
            headers=js,
        ),
        "poses": c.post(
            f"/sessions/{S}/poses", content=_dumps({"t": [v], "position": [[0, 0, 0]]}), headers=js
        ),
        "labels": c.post(
            f"/sessions/{S}/labels", content=_dumps({"label": "mug", "t": v}), headers=js
        ),
        "image.t": c.post(
            f"/sessions/{S}/image", data={"t": _q(v)}, files={"file": ("a.png", b"x", "image/png")}
        ),
        "like": c.post(
            "/search/like", content=_dumps({"sense": "text", "text": "mug", "after": v}), headers=js
        ),
        "like.image": c.post(
            "/search/like/image",
            data={"before": _q(v)},
            files={"file": ("a.png", b"x", "image/png")},
        ),
    }
    for path in ("/search", "/last", "/first", "/count", "/moments", "/where"):
        out["get" + path] = c.get(path, params={"q": "a mug", "after": _q(v)})
    for path in ("/before", "/after"):
        out["get" + path] = c.get(path, params={"anchor": "a mug", "before": _q(v)})
    out["get/at"] = c.get("/at", params={"x": 0, "y": 0, "z": 0, "r": 1, "after": _q(v)})
    out["timeline"] = c.get(f"/sessions/{S}/timeline", params={"before": _q(v)})
    return out


def _stream(base: str, v: Any) -> list[str]:
    """The WebSocket: ``t0`` (with hz) and a frame's ``t``; each answer's type."""
    ws_url = base.replace("http", "ws") + f"/sessions/{S}/touch/stream"
    frame = window(k=1, seed=9)[0]
    kinds = []
    try:
        with connect(f"{ws_url}?window=1&stride=1&hz=10&t0={_q(v)}", open_timeout=60) as ws:
            first = json.loads(ws.recv(timeout=READ_LIVENESS_S))
            kinds.append(first["type"])
            if first["type"] == "ready":
                ws.send(npy_bytes(frame))
                kinds.append(json.loads(ws.recv(timeout=READ_LIVENESS_S))["type"])
    except (InvalidStatus, ConnectionClosed):
        kinds.append("refused")
    with connect(f"{ws_url}?window=1&stride=1", open_timeout=60) as ws:
        assert json.loads(ws.recv(timeout=READ_LIVENESS_S))["type"] == "ready"
        ws.send(json.dumps({"frame": frame.tolist(), "t": v}))
        kinds.append(json.loads(ws.recv(timeout=READ_LIVENESS_S))["type"])
    return kinds


READS: list[tuple[str, dict[str, Any]]] = [
    ("/search", {"q": "holding a mug", "k": 5}),
    ("/search", {"q": "holding a mug", "k": 5, "group": "window"}),
    ("/search", {"q": "holding a mug", "k": 5, "group": "grasp"}),
    ("/search", {"q": "holding a mug", "k": 5, "group": "moment"}),
    ("/last", {"q": "holding a mug"}),
    ("/first", {"q": "holding a mug", "group": "grasp"}),
    ("/count", {"q": "holding a mug"}),
    ("/moments", {"q": "holding a mug"}),
    ("/after", {"anchor": "holding a mug"}),
    ("/sessions", {}),
    (f"/sessions/{S}/timeline", {}),
    ("/labels", {}),
]


def _reads_answer(base: str) -> None:
    with httpx.Client(base_url=base, timeout=READ_LIVENESS_S) as c:
        for path, params in READS:
            r = c.get(path, params=params)  # a hang raises ReadTimeout: the failure
            assert r.status_code == 200, (path, params, r.text)


@pytest.mark.parametrize("v", EDGES, ids=repr)
def test_every_time_door_refuses_or_stores_and_reads_answer(base: str, v: Any) -> None:
    with httpx.Client(base_url=base, timeout=120) as c:
        answers = _writes(c, v)
    kept = not isinstance(v, (bool, str)) and v in KEPT
    for name, r in answers.items():
        assert r.status_code < 500, (name, v, r.text)
        if name in ("image.t", "like.image") and r.status_code == 400:
            assert kept or v == "3", (name, v)  # the time passed; the space has no vision
            continue
        if kept or (name.startswith(TEXT_DOORS) and v == "3"):
            # a query string's or form's "3" is 3 s; labels/poses may 404/409/422 on their own
            assert r.status_code < 300 or name in ("labels", "poses"), (name, v, r.text)
        else:
            assert r.status_code == 422, (name, v, r.status_code, r.text)
            detail = r.json()["detail"]
            if isinstance(v, float) and math.isfinite(v) and abs(v) > 1e17:
                assert "seconds, not nanoseconds?" in detail, (name, detail)
    kinds = _stream(base, v)
    if isinstance(v, (bool, str)) or v not in KEPT:
        assert "stored" not in kinds[-1:] and kinds[-1] == "error", kinds
    else:
        assert kinds[-1] in ("stored", "idle"), kinds
    if "stored" in kinds or any(r.status_code in (200, 201) for r in answers.values()):
        _reads_answer(base)  # something was stored (or a read answered): every read answers


def test_the_schema_states_the_rule_on_every_time(base: str) -> None:
    """Every parameter or body field named like a time carries the rule's bounds, and the
    table above (what the property test sends) names every one of them."""
    spec = httpx.get(base + "/openapi.json", timeout=60).json()
    comps = spec["components"]["schemas"]
    names = {"t", "t_end", "after", "before", "t0"}
    found: dict[tuple[str, str], set[str]] = {}

    def bounded(schema: dict[str, Any]) -> bool:
        options = schema.get("anyOf", [schema])
        numbers = [o.get("items", o) for o in options if o.get("type") in ("number", "array")]
        return bool(numbers) and all(n.get("maximum") == MAX_SECONDS for n in numbers)

    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            for p in op.get("parameters", []):
                if p["name"] in names:
                    assert bounded(p["schema"]), (method, path, p)
                    found.setdefault((method, path), set()).add(p["name"])
            for content in op.get("requestBody", {}).get("content", {}).values():
                ref = content.get("schema", {}).get("$ref", "")
                for key, schema in comps.get(ref.split("/")[-1], {}).get("properties", {}).items():
                    if key in names:
                        assert bounded(schema), (method, path, key, schema)
                        found.setdefault((method, path), set()).add(key)
    missing = {k: v - TIME_FIELDS.get(k, set()) for k, v in found.items()}
    assert not {k: v for k, v in missing.items() if v}, missing


@pytest.mark.parametrize(
    ("value", "words"),
    [
        (1.7e18, "seconds, not nanoseconds?"),
        (1.7e15, "seconds, not microseconds?"),
        (1.7e12, "seconds, not milliseconds?"),
        (-2e10, "|t| <= 1e+10"),
        (math.nan, "finite"),
        (True, "number of seconds"),
        ("3", "number of seconds"),
        (None, "number of seconds"),
    ],
    ids=repr,
)
def test_check_time_names_the_problem(value: Any, words: str) -> None:
    with pytest.raises(InvalidInputError, match=None) as err:
        check_time(value, "t")
    assert words in str(err.value), str(err.value)


def test_check_time_keeps_the_range() -> None:
    for v in (0, -0.0, 5e-324, 1e9, MAX_SECONDS, -MAX_SECONDS, np.float32(2.5), np.int64(7)):
        assert check_time(v) == float(v)


def test_a_store_written_before_the_rule_does_not_freeze_search(tmp_path, monkeypatch) -> None:
    """A touch window at t=1e18 in a store written before the rule (the write check stood in
    by the old finite-only one): search's grasps are read in bounded rounds and answer."""
    import tactus_memory.batches as batches
    from tactus_memory.search import grasps
    from tactus_memory.where import finite_float

    memory = make_memory(tmp_path / "mem")
    with monkeypatch.context() as old:
        old.setattr(batches, "check_time", finite_float)  # the write check before the rule
        memory.add(S, "touch", window(seed=3), t=1e18)
    scans: list[int] = []
    read = grasps._read
    monkeypatch.setattr(grasps, "_read", lambda *a: scans.append(1) or read(*a))
    done: list[Any] = []
    worker = threading.Thread(
        target=lambda: done.append(memory.search("holding a mug", 5)), daemon=True
    )
    worker.start()
    worker.join(READ_LIVENESS_S)  # liveness: before the fix this never returned
    assert done and done[0][0].t == 1e18, (len(scans), done)
    assert len(scans) <= grasps.GRASP_MAX_ROUNDS
