"""Issue 36, defect 10: damage under a running server is a 503 that names what is damaged,
never a 500 and never a healthy ``/health``: a tenant's folder removed while the server runs
(that tenant's keys, and ``/health``, name the tenant; the other tenants are served as
before), and a damaged ``keys`` or ``audit`` table of the store's root (``/health`` names
the table; every keyed request is a 503 naming the keys table, not a 401). Real LanceDB, a
real uvicorn on 127.0.0.1."""

from __future__ import annotations

import shutil
from pathlib import Path

import httpx

from benchmarks.serving import serve_app
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.audit import AuditLog
from tactus_memory.storage.keys import KeyStore
from tests.helpers.fakes import HashingSpace


def _memory(path: Path) -> Memory:
    # read consistency 0: the server re-reads its keys on every request (no waiting here)
    return Memory.open(str(path), space=HashingSpace(dim=64), read_consistency_interval=0)


def _auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def _damage(table_dir: Path) -> int:
    """Remove every data file of a Lance table; returns how many there were."""
    files = list((table_dir / "data").glob("*.lance"))
    for f in files:
        f.unlink()
    return len(files)


def test_a_tenant_folder_removed_under_a_running_server_is_503_naming_it(tmp_path) -> None:
    data = tmp_path / "mem"
    memory = _memory(data)
    keys = KeyStore(str(data))
    key_a, key_b = keys.create("A", "write")[1], keys.create("B", "write")[1]
    with (
        serve_app(create_app(Settings(), memory=memory)) as base,
        httpx.Client(base_url=base, timeout=60) as c,
    ):
        for key in (key_a, key_b):
            note = {"text": "the mug is in the sink", "t": 1.0}
            r = c.post("/sessions/kitchen/text", json=note, headers=_auth(key))
            assert r.status_code == 201, r.text
        assert c.get("/health").status_code == 200
        shutil.rmtree(data / "tenants" / "B")

        for method, url, body in (
            ("GET", "/sessions", None),
            ("GET", "/search?q=mug", None),
            ("POST", "/sessions/kitchen/text", {"text": "a second note", "t": 2.0}),
        ):
            r = c.request(method, url, json=body, headers=_auth(key_b))
            assert r.status_code == 503, (url, r.status_code, r.text)
            assert "tenant 'B'" in r.json()["detail"] and str(tmp_path) not in r.text
        r = c.get("/health")
        assert r.status_code == 503 and "tenant 'B'" in r.json()["detail"], r.text
        r = c.get("/sessions", headers=_auth(key_a))  # the other tenants are served
        assert r.status_code == 200, r.text
        assert [s["id"] for s in r.json()["sessions"]] == ["kitchen"]
    assert not (data / "tenants" / "B").exists()  # nothing re-created it


def test_a_damaged_keys_table_is_503_naming_it(tmp_path) -> None:
    """The running server's ``/health`` names the damaged keys table (its keys already read
    stay in its memory); a server started on it answers every request 503 naming the
    table: not a 401 that would call a right key wrong, not a 500, not let in."""
    data = tmp_path / "mem"
    memory = _memory(data)
    key = KeyStore(str(data)).create("A", "write")[1]
    with serve_app(create_app(Settings(), memory=memory)) as base:
        assert httpx.get(f"{base}/sessions", headers=_auth(key), timeout=60).status_code == 200
        assert httpx.get(f"{base}/health", timeout=60).status_code == 200
        assert _damage(data / "keys.lance") >= 1
        r = httpx.get(f"{base}/health", timeout=60)
        assert r.status_code == 503 and "keys table" in r.json()["detail"], r.text
        assert str(tmp_path) not in r.text
    memory.close()

    with serve_app(create_app(Settings(), memory=_memory(data)), probe="/live") as base:
        for headers in (_auth(key), {}):
            r = httpx.get(f"{base}/sessions", headers=headers, timeout=60)
            assert r.status_code == 503, r.text
            assert "keys table" in r.json()["detail"] and str(tmp_path) not in r.text
        r = httpx.get(f"{base}/health", timeout=60)
        assert r.status_code == 503 and "keys table" in r.json()["detail"], r.text


def test_a_damaged_audit_table_is_503_on_health_naming_it(tmp_path) -> None:
    data = tmp_path / "mem"
    memory = _memory(data)
    audit = AuditLog(str(data))
    audit.record("k1", "default", "POST /sessions/s/text", 201, 1)
    assert audit.flush() == 1
    with (
        serve_app(create_app(Settings(), memory=memory)) as base,
        httpx.Client(base_url=base, timeout=60) as c,
    ):
        assert c.get("/health").status_code == 200
        assert _damage(data / "audit.lance") >= 1
        r = c.get("/health")
        assert r.status_code == 503 and "audit table" in r.json()["detail"], r.text
        assert c.get("/ready").status_code == 503
        assert str(tmp_path) not in r.text
