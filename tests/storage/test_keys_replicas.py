"""Keys across replicas (issue 25): two real uvicorn servers on one ``s3://`` store (moto's
S3-compatible server, tests/storage/test_s3.py's fixtures); a key created by another connection
(what
``tactus keys create`` does) works on both within the read consistency interval, its
revocation stops it on both, and a tenant's data written through one replica is its own on
the other too."""

from __future__ import annotations

from contextlib import ExitStack

import httpx

from benchmarks.serving import serve_app
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.keys import KeyStore
from tests.helpers.replicas import STALENESS, open_replica, wait_for
from tests.helpers.s3 import WAIT_S


def test_a_key_made_elsewhere_works_and_is_revoked_on_every_replica(uri: str) -> None:  # noqa: F811
    first = open_replica(uri, maintain=True)
    second = open_replica(uri, maintain=False)
    with ExitStack() as stack:
        bases = [
            stack.enter_context(serve_app(create_app(Settings(token="op-token"), memory=m)))
            for m in (first, second)
        ]
        clients = [stack.enter_context(httpx.Client(base_url=b, timeout=60)) for b in bases]
        keys = KeyStore(uri, refresh=STALENESS)  # another process: the CLI's connection
        key_id, key = keys.create("fleet-a", "write")
        _, other = keys.create("fleet-b", "read")
        auth = {"Authorization": f"Bearer {key}"}

        def accepted(c: httpx.Client, headers: dict[str, str]) -> bool:
            return c.get("/sessions", headers=headers).status_code == 200

        for c in clients:
            wait_for(lambda c=c: accepted(c, auth), WAIT_S)
        r = clients[0].post("/sessions/s1/text", json={"text": "a note", "t": 1.0}, headers=auth)
        assert r.status_code == 201, r.text
        wait_for(lambda: clients[1].get("/sessions/s1", headers=auth).status_code == 200, WAIT_S)
        b_auth = {"Authorization": f"Bearer {other}"}
        wait_for(lambda: accepted(clients[1], b_auth), WAIT_S)
        assert clients[1].get("/sessions/s1", headers=b_auth).status_code == 404
        assert clients[1].get("/sessions", headers=b_auth).json() == {"sessions": []}
        keys.revoke(key_id)
        for c in clients:
            wait_for(lambda c=c: c.get("/sessions", headers=auth).status_code == 401, WAIT_S)
        assert accepted(clients[0], b_auth)  # the other key still works
