"""Keys, scopes and tenants on a real uvicorn server (issue 25): every route of the app against
tenants x scopes x session prefixes, another tenant's data (and a session outside a key's
prefix) reading exactly like missing data on every route, unknown tenants, revoked and
expired keys, the WebSocket stream and the audit log."""

from __future__ import annotations

import json
import re
import time

import httpx
import pytest
from starlette.routing import Route

from benchmarks.serving import serve_app
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.audit import AuditLog
from tactus_memory.storage.keys import KeyStore
from tests.helpers.places import POSES
from tests.helpers.routes import _concrete, _is_open, flat_routes
from tests.helpers.service import make_memory, npy_bytes, touch_json, window

OPERATOR = "operator-s3cret"
#: what each route needs, written out here (not read from the service): reads by default,
#: these POST/PUT routes write, these routes need admin
WRITES = {
    "add_text", "add_vectors", "add_image", "add_touch", "add_poses", "segment_episodes",
    "set_clock", "touch_stream", "teach", "add_windows", "windows_stream",
}  # fmt: skip
ADMIN = {"delete_session", "add_sense", "forget_label"}  # DELETE needs admin
SCOPES = ("read", "write", "admin")
#: the session-id prefix of tenant A's limited keys (``--sessions lab-``)
LAB = "lab-"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """One real server on a store with keys for tenants A and B at each scope."""
    data = tmp_path_factory.mktemp("store") / "mem"
    memory = make_memory(data)
    keys = KeyStore(str(data), refresh=0.2)
    made = {(t, s): keys.create(t, s) for t in ("A", "B") for s in SCOPES}
    made |= {("A", s, LAB): keys.create("A", s, sessions=LAB) for s in SCOPES}
    app = create_app(Settings(token=OPERATOR), memory=memory)
    with serve_app(app) as base:
        yield {"base": base, "keys": keys, "made": made, "app": app, "data": data}


def _h(server, tenant: str, scope: str, *prefix: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {server['made'][(tenant, scope, *prefix)][1]}"}


def _need(name: str) -> str:
    return "admin" if name in ADMIN else "write" if name in WRITES else "read"


def test_every_route_x_scope(server) -> None:
    """No key, a wrong key, a key of an unknown id: 401 everywhere; a key whose scope falls
    short: 403; enough scope: neither."""
    app, base = server["app"], server["base"]
    seen = 0
    with httpx.Client(base_url=base, timeout=30) as c:
        for route in flat_routes(app):
            if not isinstance(route, Route) or _is_open(route.path):
                continue
            for method in sorted((route.methods or set()) - {"HEAD", "OPTIONS"}):
                url = _concrete(route.path)
                for bad in ({}, {"Authorization": "Bearer tk_000000000000_nope"}):
                    assert c.request(method, url, headers=bad).status_code == 401, url
                for scope in SCOPES:
                    status = c.request(method, url, headers=_h(server, "A", scope)).status_code
                    short = SCOPES.index(scope) < SCOPES.index(_need(route.name))
                    assert (status == 403) == short, f"{method} {url} {scope}: {status}"
                    assert status != 401, f"{method} {url} {scope}"
                    # a key limited to lab-*: the same scopes; "s1" in a path is outside
                    r = c.request(method, url, headers=_h(server, "A", scope, LAB))
                    assert (r.status_code == 403) == short, f"{method} {url} {scope} lab"
                    if not short and "{session}" in route.path:
                        assert r.status_code == 404, f"{method} {url} {scope} lab"
                        assert r.json()["detail"] == "no session 's1'", (url, r.text)
                seen += 1
    assert seen >= 25


def _fill(c: httpx.Client, headers: dict[str, str], session: str, word: str) -> list[str]:
    """A session with a note, a touch window, poses and a clock offset; returns item ids."""
    ids = []
    r = c.post(
        f"/sessions/{session}/text", json={"text": f"the {word} mug", "t": 1.0}, headers=headers
    )
    assert r.status_code == 201, r.text
    ids += r.json()["ids"]
    r = c.post(f"/sessions/{session}/touch", json=touch_json(t=1.5), headers=headers)
    assert r.status_code == 201, r.text
    ids += r.json()["ids"]
    poses = {"content-type": "application/x-npy", **headers}
    r = c.post(f"/sessions/{session}/poses", content=npy_bytes(POSES), headers=poses)
    assert r.status_code == 201, r.text
    r = c.put(f"/sessions/{session}/clock", json={"sense": "text", "offset": 0.5}, headers=headers)
    assert r.status_code == 200, r.text
    return ids


#: read routes with a session in their path, or a session query parameter
SESSION_READS = [
    "/sessions/{s}", "/sessions/{s}/timeline", "/sessions/{s}/poses", "/sessions/{s}/clock",
    "/sessions/{s}/export.rrd", "/search?q=mug&session={s}", "/moments?q=mug&session={s}",
    "/last?q=mug&session={s}", "/first?q=mug&session={s}", "/count?q=mug&session={s}",
    "/where?q=mug&session={s}", "/before?q=mug&anchor=mug&session={s}",
    "/after?q=mug&anchor=mug&session={s}",
]  # fmt: skip
ITEM_READS = ["/items/{i}/touch.png", "/items/{i}/touch.json", "/items/{i}/image.png"]
GLOBAL_READS = [
    "/sessions", "/search?q=mug", "/moments?q=mug", "/count?q=mug", "/last?q=mug",
    "/first?q=mug", "/before?q=mug&anchor=mug", "/after?q=mug&anchor=mug",
    "/where?q=mug", "/at?x=0&y=0&z=0&r=100", "/senses",
]  # fmt: skip


def _same(a: httpx.Response, b: httpx.Response, a_id: str, b_id: str) -> None:
    assert a.status_code == b.status_code, (a.url, a.status_code, b.status_code)
    assert a.content.replace(a_id.encode(), b"X") == b.content.replace(b_id.encode(), b"X"), a.url


def test_another_tenants_data_reads_exactly_like_missing_data(server) -> None:
    ha, hb = _h(server, "A", "admin"), _h(server, "B", "admin")
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        a_ids = _fill(c, ha, "wall-a", "zanzibar")
        b_ids = _fill(c, hb, "wall-b", "quokka")
        for path in SESSION_READS:  # A's session, asked by B == a session nobody has
            theirs = c.get(path.format(s="wall-a"), headers=hb)
            nobody = c.get(path.format(s="wall-zz"), headers=hb)
            _same(theirs, nobody, "wall-a", "wall-zz")
            mine = c.get(path.format(s="wall-a"), headers=ha)
            assert mine.status_code == 200, (path, mine.text)
        for path in ITEM_READS:
            for a_id in a_ids:
                _same(c.get(path.format(i=a_id), headers=hb), c.get(path.format(i="zz-none"),
                      headers=hb), a_id, "zz-none")  # fmt: skip
        for path in GLOBAL_READS:  # nothing of A in anything B can list or search
            body = c.get(path, headers=hb)
            assert body.status_code == 200, (path, body.text)
            for secret in ("zanzibar", "wall-a", *a_ids):
                assert secret not in body.text, (path, secret)
        assert "wall-b" in c.get("/sessions", headers=hb).text
        assert "zanzibar" in c.get("/search?q=zanzibar", headers=ha).text
        # B writes A's session name and A's item ids: no conflict, A's items untouched
        r = c.post("/sessions/wall-a/text", json={"text": "b note", "t": 2.0, "id": a_ids[0]},
                   headers=hb)  # fmt: skip
        assert r.status_code == 201, r.text
        assert c.delete("/sessions/wall-a", headers=hb).json()["deleted"] == 1  # B's own
        assert c.delete("/sessions/wall-a", headers=hb).status_code == 404
        assert c.get("/sessions/wall-a", headers=ha).json()["n"] == 2  # A's: untouched
        assert c.get(f"/items/{a_ids[1]}/touch.json", headers=ha).status_code == 200
        assert c.get(f"/items/{b_ids[1]}/touch.json", headers=ha).status_code == 404
        # the operator's token reaches a tenant through its header
        op = {"Authorization": f"Bearer {OPERATOR}", "X-Tactus-Tenant": "A"}
        assert c.get("/sessions/wall-a", headers=op).json()["n"] == 2
        assert c.get("/sessions/wall-a", headers={**op, "X-Tactus-Tenant": "B"}).status_code == 404
        # a key's own tenant wins over the header
        assert c.get("/sessions/wall-a", headers={**hb, "X-Tactus-Tenant": "A"}).status_code == 404


def test_the_stream_writes_into_the_keys_tenant_only(server) -> None:
    from websockets.sync.client import connect

    port = server["base"].rsplit(":", 1)[1]
    url = f"ws://127.0.0.1:{port}/sessions/wall-ws/touch/stream?window=8&stride=8&t0=0&hz=100"
    key = server["made"][("B", "write")][1]
    with connect(f"{url}&token={key}", open_timeout=30) as ws:
        assert json.loads(ws.recv(timeout=30))["type"] == "ready"
        ws.send(npy_bytes(window(k=8, seed=3)))
        assert json.loads(ws.recv(timeout=60))["type"] == "stored"
    # a read key may not stream: the socket is refused with the problem (as for a 401)
    with connect(f"{url}&token={server['made'][('B', 'read')][1]}", open_timeout=30) as ws:
        msg = json.loads(ws.recv(timeout=30))
        assert msg["type"] == "error" and msg["error"]["status"] == 403, msg
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        assert c.get("/sessions/wall-ws", headers=_h(server, "B", "read")).json()["n"] == 1
        assert c.get("/sessions/wall-ws", headers=_h(server, "A", "read")).status_code == 404


def test_revoked_and_expired_keys_are_refused(server) -> None:
    keys: KeyStore = server["keys"]
    _, revoked = keys.create("A", "read")
    # a key with an expiry works until then; one whose expiry has passed is refused. Two keys,
    # so no wall clock decides the test: on a busy machine more than a short life can pass
    # before the first request
    _, lasting = keys.create("A", "read", expires_days=1.0)
    _, expiring = keys.create("A", "read", expires_days=0.5 / 86400)  # half a second
    expires_at = time.time() + 0.5
    with httpx.Client(base_url=server["base"], timeout=30) as c:

        def status(key: str) -> int:
            return c.get("/sessions", headers={"Authorization": f"Bearer {key}"}).status_code

        deadline = time.monotonic() + 30  # a new key works within the re-read interval
        while status(revoked) != 200 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert status(revoked) == 200 and status(lasting) == 200
        other = KeyStore(str(server["data"]))  # another process's connection revokes it
        other.revoke(revoked.split("_")[1])
        while status(revoked) != 401 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert status(revoked) == 401
        time.sleep(max(0.0, expires_at - time.time()))
        while status(expiring) != 401 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert status(expiring) == 401 and status(lasting) == 200
        listed = {k.key_id: k for k in other.list()}
        assert listed[revoked.split("_")[1]].revoked is not None
        assert listed[revoked.split("_")[1]].last_used is not None


def test_the_audit_log_names_key_tenant_route_and_count_never_key_or_payload(server) -> None:
    key_id, key = server["made"][("A", "write")]
    t0 = time.time()
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        h = {"Authorization": f"Bearer {key}"}
        body = {"windows": [window(seed=s).tolist() for s in (7, 8, 9)], "t": [1.0, 2.0, 3.0]}
        assert c.post("/sessions/audited/touch", json=body, headers=h).status_code == 201
        r = c.post("/sessions/audited/text", json={"text": "secret-payload-xyz", "t": 1}, headers=h)
        assert r.status_code == 201
        assert c.delete("/sessions/audited", headers=h).status_code == 403  # refused: logged
        admin = _h(server, "A", "admin")
        assert c.delete("/sessions/audited", headers=admin).json()["deleted"] == 4
        assert c.get("/search?q=secret", headers=h).status_code == 200  # a read: not logged
    log = AuditLog(str(server["data"]))
    deadline = time.monotonic() + 30
    while len(log.entries(tenant="A", since=t0)) < 4 and time.monotonic() < deadline:
        time.sleep(0.2)
    mine = [e for e in log.entries(tenant="A") if "audited" not in e.route]  # templates only
    got = [(e.key_id, e.route, e.status, e.count) for e in log.entries(tenant="A", since=t0)]
    assert (key_id, "POST /sessions/{session}/touch", 201, 3) in got
    assert (key_id, "POST /sessions/{session}/text", 201, 1) in got
    assert (key_id, "DELETE /sessions/{session}", 403, 0) in got
    admin_id = server["made"][("A", "admin")][0]
    assert (admin_id, "DELETE /sessions/{session}", 200, 4) in got
    assert not any(e.route.startswith("GET") for e in log.entries())
    assert len(mine) == len(log.entries(tenant="A"))
    dump = json.dumps([e.__dict__ for e in log.entries()])
    assert key not in dump and "secret-payload-xyz" not in dump
    assert not re.search(r"tk_[0-9a-f]{12}_", dump)


def _session_routes(app) -> list[tuple[str, str]]:
    """(method, path template) of every HTTP route with a session in its path."""
    return [
        (method, route.path)
        for route in flat_routes(app)
        if isinstance(route, Route) and "{session}" in route.path
        for method in sorted((route.methods or set()) - {"HEAD", "OPTIONS"})
    ]


def test_a_key_limited_to_sessions_sees_nothing_outside_its_prefix(server) -> None:
    """``--sessions lab-``: every route with a session in its path answers a session outside
    the prefix (existing or not) with the same 404 and changes nothing; every search,
    listing, count and item read sees the sessions under the prefix only."""
    ha, lab = _h(server, "A", "admin"), _h(server, "A", "admin", LAB)
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        in_ids = _fill(c, lab, "lab-1", "pelican")  # the limited key writes its own sessions
        out_ids = _fill(c, ha, "home-1", "narwhal")  # the unlimited key of the same tenant
        before = c.get("/sessions/home-1", headers=ha).json()
        routes = _session_routes(server["app"])
        assert len(routes) >= 10
        for method, path in routes:  # writes, reads, deletes, exports, images, poses, clock
            theirs = c.request(method, _concrete(path.replace("{session}", "home-1")),
                               headers=lab, json={"text": "x", "t": 1.0})  # fmt: skip
            nobody = c.request(method, _concrete(path.replace("{session}", "home-zz")),
                               headers=lab, json={"text": "x", "t": 1.0})  # fmt: skip
            assert theirs.status_code == 404, (method, path, theirs.text)
            _same(theirs, nobody, "home-1", "home-zz")
        r = c.post("/sessions/home-2/text", json={"text": "sneaky", "t": 1.0}, headers=lab)
        assert r.status_code == 404
        assert c.get("/sessions/home-2", headers=ha).status_code == 404  # nothing written
        assert c.get("/sessions/home-1", headers=ha).json() == before  # nothing changed
        for path in SESSION_READS:  # the session as a query parameter too
            _same(c.get(path.format(s="home-1"), headers=lab),
                  c.get(path.format(s="home-zz"), headers=lab), "home-1", "home-zz")  # fmt: skip
            assert c.get(path.format(s="lab-1"), headers=lab).status_code == 200, path
        for path in ITEM_READS:
            for out_id in out_ids:
                _same(c.get(path.format(i=out_id), headers=lab),
                      c.get(path.format(i="zz-none"), headers=lab), out_id, "zz-none")  # fmt: skip
        assert c.get(f"/items/{in_ids[1]}/touch.json", headers=lab).status_code == 200
        for path in GLOBAL_READS:
            body = c.get(path, headers=lab)
            assert body.status_code == 200, (path, body.text)
            for secret in ("narwhal", "home-1", *out_ids):
                assert secret not in body.text, (path, secret)
        assert [s["id"] for s in c.get("/sessions", headers=lab).json()["sessions"]] == ["lab-1"]
        assert "home-1" in c.get("/sessions", headers=ha).text
        assert "pelican" in c.get("/search?q=pelican", headers=lab).text
        for like in (
            {"sense": "touch", "frames": window().tolist()},
            {"sense": "text", "text": "narwhal"},
        ):
            hits = c.post("/search/like", json={**like, "k": 10}, headers=lab).json()["hits"]
            assert {h["session"] for h in hits} == {"lab-1"}, hits  # both sessions hold it
        rows = {s["name"]: s["rows"] for s in c.get("/senses", headers=lab).json()["senses"]}
        assert rows["text"] == 1 and rows["touch"] == 1, rows  # lab-1's rows, not home-1's
        assert c.delete("/sessions/home-1", headers=lab).status_code == 404
        assert c.get("/sessions/home-1", headers=ha).json() == before
    from websockets.sync.client import connect

    port = server["base"].rsplit(":", 1)[1]
    key = server["made"][("A", "write", LAB)][1]
    for session, first in (("home-1", "error"), ("lab-ws", "ready")):
        url = f"ws://127.0.0.1:{port}/sessions/{session}/touch/stream?window=8&stride=8&t0=0&hz=100"
        with connect(f"{url}&token={key}", open_timeout=30) as ws:
            msg = json.loads(ws.recv(timeout=30))
            assert msg["type"] == first, msg
            if first == "error":
                assert msg["error"]["status"] == 404, msg
            else:
                ws.send(npy_bytes(window(k=8, seed=4)))
                assert json.loads(ws.recv(timeout=60))["type"] == "stored"
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        assert c.get("/sessions/lab-ws", headers=ha).json()["n"] == 1
        assert c.get("/sessions/home-1", headers=ha).json() == before


def test_an_unknown_tenant_is_a_404_and_never_created(server) -> None:
    """The operator's X-Tactus-Tenant naming a tenant no key names and no database holds:
    404 unknown-tenant for reads and writes, and no database appears; the tenant's first key
    brings it into being."""
    op = {"Authorization": f"Bearer {OPERATOR}", "X-Tactus-Tenant": "tpyo"}
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        note = {"text": "x", "t": 1.0}
        for method, url, body in (
            ("GET", "/sessions", None), ("GET", "/search?q=mug", None),
            ("POST", "/sessions/s1/text", note),
        ):  # fmt: skip
            r = c.request(method, url, headers=op, json=body)
            assert r.status_code == 404, (url, r.text)
            assert r.json()["type"].endswith(":unknown-tenant"), r.text
        assert not (server["data"] / "tenants" / "tpyo").exists()
        log, deadline = AuditLog(str(server["data"])), time.monotonic() + 30
        while not log.entries(tenant="tpyo") and time.monotonic() < deadline:
            time.sleep(0.2)  # the refused write is logged, under the name it gave
        got = [(e.key_id, e.route, e.status) for e in log.entries(tenant="tpyo")]
        assert got == [("operator", "POST /sessions/{session}/text", 404)], got
        server["keys"].create("tpyo", "read")
        deadline = time.monotonic() + 30  # seen within the keys' re-read interval
        while c.get("/sessions", headers=op).status_code != 200 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert c.get("/sessions", headers=op).json()["sessions"] == []
        r = c.post("/sessions/s1/text", json={"text": "now it exists", "t": 1.0}, headers=op)
        assert r.status_code == 201, r.text


def test_the_client_acts_for_the_operators_tenant(server) -> None:
    """``Client(url, token, tenant=...)`` sends the operator's tenant header on every call
    and on the touch stream; an unknown tenant raises UnknownTenantError (404)."""
    from tactus_memory.client.main import Client
    from tactus_memory.errors import UnknownTenantError

    with Client(server["base"], OPERATOR, tenant="B") as b:
        b.add("client-b", "text", "a note of the operator in B", t=1.0)
        with b.stream_touch("client-b", window=8, stride=8, t0=0.0, hz=100.0) as stream:
            stream.send(window(k=8, seed=5))
            assert stream.wait(60) and len(stream.ids) == 1, stream.errors
        assert b.session("client-b").n == 2
    with httpx.Client(base_url=server["base"], timeout=30) as c:
        assert c.get("/sessions/client-b", headers=_h(server, "B", "read")).json()["n"] == 2
        assert c.get("/sessions/client-b", headers=_h(server, "A", "read")).status_code == 404
    with (
        Client(server["base"], OPERATOR, tenant="nosuch") as nobody,
        pytest.raises(UnknownTenantError),
    ):
        nobody.sessions()
