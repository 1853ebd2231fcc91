"""Issue 36, defect 5: the secret-check throttle is atomic (at most FAILED_CHECKS_PER_S
scrypt checks per key id and second, however many threads), answers 429 with Retry-After
(never a 401 that would say the key is wrong), and a key that has not failed is never locked
out: it gets in once the second is over. The clock is frozen, so the bound is checked
exactly, on a real LanceDB key table and a real uvicorn server."""

from __future__ import annotations

import threading

import httpx
import pytest

from benchmarks.serving import serve_app
from tactus_memory.errors import ThrottledError
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage import keys as keys_module
from tactus_memory.storage.keys import FAILED_CHECKS_PER_S, KeyStore
from tests.helpers.service import make_memory


class Clock:
    def __init__(self) -> None:
        self.now = 1000.25

    def __call__(self) -> float:
        return self.now


def test_flood_of_wrong_secrets_gets_at_most_the_bound(tmp_path, monkeypatch) -> None:
    root = str(tmp_path / "mem")
    store = KeyStore(root, refresh=3600)
    key_id, key = store.create("default", "write")
    store.clock = clock = Clock()
    scrypts = []
    real_hash = keys_module._hash
    monkeypatch.setattr(
        keys_module, "_hash", lambda s, salt: (scrypts.append(s), real_hash(s, salt))[1]
    )
    outcomes: list[str] = []
    lock = threading.Lock()

    def guess(n: int) -> None:
        for j in range(n):
            try:
                got = store.verify(f"tk_{key_id}_wrong{j}")
                what = "ok" if got else "refused"
            except ThrottledError as exc:
                assert 0 < exc.retry_after <= 1
                what = "throttled"
            with lock:
                outcomes.append(what)

    threads = [threading.Thread(target=guess, args=(6,)) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert len(scrypts) == FAILED_CHECKS_PER_S  # exactly the bound, 16 threads or not
    assert outcomes.count("refused") == FAILED_CHECKS_PER_S
    assert outcomes.count("throttled") == 96 - FAILED_CHECKS_PER_S and "ok" not in outcomes
    # the right key during the flood: 429, never "wrong" (None); once the second is over, in
    with pytest.raises(ThrottledError):
        store.verify(key)
    clock.now += 1.0
    assert store.verify(key).key_id == key_id
    # a right key gives its slot back: five checks of new right spellings never throttle
    _, other = store.create("default", "read")
    assert store.verify(other) is not None


def test_server_answers_429_with_retry_after(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem", touch=False)
    key_id, key = KeyStore(str(tmp_path / "mem")).create("default", "read")
    app = create_app(Settings(), memory=memory)
    app.state.tactus.gate.keys.clock = clock = Clock()
    with serve_app(app) as base:
        statuses = []
        for j in range(FAILED_CHECKS_PER_S + 2):
            auth = {"Authorization": f"Bearer tk_{key_id}_wrong{j}"}
            statuses.append(httpx.get(f"{base}/sessions", headers=auth, timeout=60))
        assert [r.status_code for r in statuses] == [401] * FAILED_CHECKS_PER_S + [429, 429]
        assert statuses[-1].headers["retry-after"] == "1"
        assert "too many key checks" in statuses[-1].json()["detail"]
        auth = {"Authorization": f"Bearer {key}"}
        r = httpx.get(f"{base}/sessions", headers=auth, timeout=60)
        assert r.status_code == 429 and r.headers["retry-after"] == "1"  # not a 401
        clock.now += 1.0
        assert httpx.get(f"{base}/sessions", headers=auth, timeout=60).status_code == 200
