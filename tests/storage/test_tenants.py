"""Tenants in Python (issue 25): ``Memory.open(path, tenant=...)`` is a wall, on a real store."""

from __future__ import annotations

import json

import pytest

from tactus_memory.errors import InvalidIdError, NotFoundError
from tactus_memory.identity import DEFAULT_TENANT
from tactus_memory.memory.main import Memory
from tactus_memory.storage.tenants import tenant_uri
from tests.helpers.fakes import HashingSpace


def _open(path, tenant: str = DEFAULT_TENANT) -> Memory:
    return Memory.open(str(path), HashingSpace(), tenant=tenant, background=False)


def test_two_tenants_share_a_store_but_not_a_session(tmp_path) -> None:
    a, b = _open(tmp_path, "A"), _open(tmp_path, "B")
    a.add("s1", "text", "a red mug on the shelf", t=1.0, id="x1")
    b.add("s1", "text", "a blue bowl in the sink", t=2.0, id="x1")  # same id: no conflict
    assert [s.id for s in a.sessions()] == ["s1"]
    assert a.session("s1").n == 1 and b.session("s1").n == 1
    assert a.get_item("x1").text == "a red mug on the shelf"
    assert b.get_item("x1").text == "a blue bowl in the sink"
    assert [h.text for h in a.search("bowl sink", k=5)] == ["a red mug on the shelf"]
    assert a.count("bowl", session="s1") <= 1
    b.delete_session("s1")
    assert a.get_item("x1").text == "a red mug on the shelf"  # A's s1 untouched
    with pytest.raises(NotFoundError):
        b.session("s1")


def test_the_default_tenant_is_the_root_and_older_stores_open_as_it(tmp_path) -> None:
    old = Memory.open(str(tmp_path), HashingSpace(), background=False)  # no tenant: as before
    old.add("s1", "text", "written before tenants", t=1.0)
    again = _open(tmp_path, DEFAULT_TENANT)
    assert again.tenant == DEFAULT_TENANT and again.store.uri == str(tmp_path)
    assert [s.id for s in again.sessions()] == ["s1"]
    other = _open(tmp_path, "A")
    assert other.sessions() == []
    assert other.store.uri == tenant_uri(str(tmp_path), "A") == f"{tmp_path}/tenants/A"


@pytest.mark.parametrize("bad", ["", "../x", "a/b", "x" * 129, " A"])
def test_a_tenant_name_is_an_id(tmp_path, bad: str) -> None:
    with pytest.raises(InvalidIdError, match="tenant"):
        _open(tmp_path, bad)


def test_the_keys_and_audit_commands(tmp_path) -> None:
    from typer.testing import CliRunner

    from tactus_memory.cli import app
    from tactus_memory.storage.keys import KeyStore

    data = str(tmp_path / "mem")

    def run(*args: str, code: int = 0) -> str:
        res = CliRunner().invoke(app, [*args, "--data", data])
        assert res.exit_code == code, res.output
        return res.output

    first = run("keys", "create", "--tenant", "default", "--scope", "admin")  # a store's first
    admin_id = first.strip().splitlines()[-1].split("_")[1]
    out = run("keys", "create", "--tenant", "A", "--scope", "write", "--expires", "30")
    key = out.strip().splitlines()[-1]  # the key, alone on the last line
    key_id = key.split("_")[1]
    info = KeyStore(data).verify(key)
    assert info is not None and (info.tenant, info.scope) == ("A", "write")
    listed = run("keys", "list")
    assert key_id in listed and "A  write" in listed and key not in listed
    assert key.split("_", 2)[2] not in run("keys", "list", "--json")
    assert f"revoked key {key_id}" in run("keys", "revoke", key_id)
    assert KeyStore(data).verify(key) is None
    assert "revoked" in run("keys", "list")
    assert "no key" in run("keys", "revoke", "nope", code=2)
    assert "scope" in run("keys", "create", "--tenant", "A", "--scope", "root", code=2)
    assert "tenant" in run("keys", "create", "--tenant", "a/b", code=2)
    audit = run("audit", "--json").splitlines()
    routes = [json.loads(line)["route"] for line in audit]
    assert routes == [
        f"cli: tactus keys create {admin_id}",
        f"cli: tactus keys create {key_id}",
        f"cli: tactus keys revoke {key_id}",
    ]
    assert key not in "".join(audit)
    assert run("audit", "--tenant", "B") == ""
    out = run("keys", "create", "--tenant", "A", "--sessions", "lab-", "--scope", "write")
    limited = KeyStore(data).verify(out.strip().splitlines()[-1])
    assert limited is not None and limited.sessions == "lab-" and "sessions lab-*" in out
    assert "sessions lab-*" in run("keys", "list")
    assert "session prefix" in run("keys", "create", "--tenant", "A", "--sessions", "a b", code=2)


def test_maintain_covers_every_tenant_and_the_key_and_audit_tables(tmp_path) -> None:
    import lancedb
    from typer.testing import CliRunner

    from tactus_memory.cli import app
    from tactus_memory.storage.audit import AUDIT, AuditLog
    from tactus_memory.storage.keys import KEYS, KeyStore

    root = str(tmp_path / "mem")
    for tenant in (DEFAULT_TENANT, "A"):
        mem = _open(root, tenant)
        for i in range(3):
            mem.add("s1", "text", f"note {i}", t=float(i))
    KeyStore(root).create("B", "read")  # B: a key, no data yet (nothing to maintain)
    log = AuditLog(root)
    for _ in range(3):
        log.record("k1", "A", "POST /sessions/{session}/text", 201, 1)
        log.flush()
    db = lancedb.connect(root)
    assert len(db.open_table(AUDIT).list_versions()) >= 3
    res = CliRunner().invoke(app, ["maintain", "--once", "--retain", "0", "--data", root])
    assert res.exit_code == 0, res.output
    lines = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    assert {line.get("tenant") for line in lines} == {None, "A"}
    assert {line["table"] for line in lines if line.get("tenant") == "A"} >= {"items.lance"}
    for name in (AUDIT, KEYS):
        assert len(db.open_table(name).list_versions()) == 1, name
    assert len(log.entries()) == 3  # compacted, nothing lost


def test_maintain_labels_each_tenants_retention_even_when_a_store_is_skipped(
    tmp_path, monkeypatch
) -> None:
    """A store maintenance skips (damaged or busy: no table reports this pass) still gets its
    own retention line, and the next tenant's line names that tenant."""
    from typer.testing import CliRunner

    from tactus_memory.cli import app
    from tactus_memory.storage.store import Store

    root = str(tmp_path / "mem")
    for tenant in (DEFAULT_TENANT, "A"):
        _open(root, tenant).add("s1", "text", "a note", t=0.0)
    monkeypatch.setenv("TACTUS_RETAIN_DAYS", "365")
    real = Store.maintain

    def maintain(self: Store, **kw):
        if self.retention.tenant == DEFAULT_TENANT:
            return False  # as a damaged store is skipped
        return real(self, **kw)

    monkeypatch.setattr(Store, "maintain", maintain)
    res = CliRunner().invoke(app, ["maintain", "--once", "--retain", "0", "--data", root])
    assert res.exit_code == 0, res.output
    assert "maintenance pass failed" not in res.output
    lines = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    assert [line.get("tenant") for line in lines if "retention" in line] == [None, "A"]


def test_guessing_a_keys_secret_is_throttled_per_key_id(tmp_path) -> None:
    from tactus_memory.errors import ThrottledError
    from tactus_memory.storage.keys import FAILED_CHECKS_PER_S, KeyStore

    now = [1000.5]
    store = KeyStore(str(tmp_path), refresh=1e9)
    store.clock = lambda: now[0]
    key_id, key = store.create("A", "read")
    other_id, other = store.create("A", "write")
    assert store.verify(other) is not None  # checked before: remembered
    for i in range(FAILED_CHECKS_PER_S):
        assert store.verify(f"tk_{key_id}_wrong{i}") is None
    with pytest.raises(ThrottledError):  # this second's checks are spent: 429, not "wrong"
        store.verify(key)
    assert store.verify(other) is not None  # another id, and a remembered key: unaffected
    now[0] += 1.0
    info = store.verify(key)
    assert info is not None and info.key_id == key_id and other_id != key_id


def test_sessions_under_a_prefix_limit_every_read_of_a_memory(tmp_path) -> None:
    """``where.sessions_under``: what a key made with ``--sessions PREFIX`` sees (the server
    sets it per request): sessions, items, searches, counts, rows per sense and deletes."""
    from tactus_memory.where import sessions_under

    mem = _open(tmp_path, "A")
    mem.add("lab-1", "text", "a red mug on the shelf", t=1.0, id="in1")
    mem.add("home-1", "text", "a red mug in the sink", t=1.0, id="out1")
    with sessions_under("lab-"):
        assert [s.id for s in mem.sessions()] == ["lab-1"]
        assert {h.session for h in mem.search("red mug", k=5)} == {"lab-1"}
        assert mem.count("a red mug in the sink") == 0  # home-1's note, 1 below
        assert {i.name: i.rows for i in mem.sense_info()}["text"] == 1
        with pytest.raises(NotFoundError):
            mem.get_item("out1")
        with pytest.raises(NotFoundError):
            mem.session("home-1")
        assert mem.delete(["in1", "out1"]) == 1  # only its own
        with sessions_under(None):  # a tenant-wide read inside
            assert len(mem.sessions()) == 1
    assert [s.id for s in mem.sessions()] == ["home-1"]
    assert mem.count("a red mug in the sink") == 1
    assert mem.get_item("out1").text == "a red mug in the sink"


def test_a_tenant_exists_once_a_key_names_it_or_it_holds_data(tmp_path) -> None:
    from tactus_memory.storage.tenants import tenant_exists

    root = str(tmp_path / "mem")
    assert tenant_exists(root, DEFAULT_TENANT)
    assert not tenant_exists(root, "A") and not (tmp_path / "mem" / "tenants" / "A").exists()
    assert tenant_exists(root, "A", named={"A"})
    _open(root, "B").add("s1", "text", "a note", t=1.0)
    assert tenant_exists(root, "B")
