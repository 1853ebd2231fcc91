"""Creating a key never locks an open server's data by surprise (issue 38): a store's first
key must be an admin key of the default tenant (one line, exit 2 otherwise), on a real uvicorn
server started without a token or keys; ``tactus keys revoke`` takes the ids ``tactus keys
list`` prints (and the key itself), and refuses to revoke the default tenant's last live admin
key unless told ``--last``."""

from __future__ import annotations

import time

import httpx
from typer.testing import CliRunner

from benchmarks.serving import serve_app
from tactus_memory.cli import app
from tactus_memory.identity import DEFAULT_TENANT
from tactus_memory.storage.keys import KeyStore
from tests.helpers.service import make_memory


def cli(data: str, *args: str, code: int = 0) -> str:
    res = CliRunner().invoke(app, [*args, "--data", data])
    assert res.exit_code == code, res.output
    return res.output


def wait_for(check, what: str, bound_s: float = 60.0) -> None:
    """Poll ``check`` (a liveness bound only: the key table is re-read every second)."""
    deadline = time.monotonic() + bound_s
    while not check():
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


def test_a_tenant_key_on_an_open_store_is_refused_and_the_server_stays_open(tmp_path) -> None:
    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    data = str(tmp_path / "mem")
    memory = make_memory(tmp_path / "mem", touch=False)
    memory.add("s1", "text", "the mug is on the shelf", t=1.0)
    with serve_app(create_app(Settings(), memory=memory)) as base:
        assert httpx.get(base + "/sessions", timeout=30).status_code == 200  # open
        for scope in ("write", "admin"):
            out = cli(data, "keys", "create", "--tenant", "kitchen", "--scope", scope, code=2)
            assert "no keys" in out and f"--tenant {DEFAULT_TENANT} --scope admin" in out
            assert len(out.strip().splitlines()) == 1, out  # one line
        out = cli(data, "keys", "create", "--tenant", DEFAULT_TENANT, "--scope", "read", code=2)
        assert "admin key of the default tenant" in out
        assert KeyStore(data).list() == []  # nothing was made
        time.sleep(1.5)  # past the server's key-table refresh (1 s): still open
        got = httpx.get(base + "/sessions", timeout=30)
        assert got.status_code == 200 and [s["id"] for s in got.json()["sessions"]] == ["s1"]

        out = cli(data, "keys", "create", "--tenant", DEFAULT_TENANT, "--scope", "admin")
        assert "need a key or the token for every request" in out
        admin = out.strip().splitlines()[-1]
        out = cli(data, "keys", "create", "--tenant", "kitchen", "--scope", "write")
        kitchen = out.strip().splitlines()[-1]  # later keys: any tenant, any scope

        def keyed() -> bool:
            return httpx.get(base + "/sessions", timeout=30).status_code == 401

        wait_for(keyed, "the server never asked for a key once the admin key existed")
        # the operator's admin key keeps the default tenant's data reachable
        auth = {"Authorization": f"Bearer {admin}"}
        got = httpx.get(base + "/sessions", headers=auth, timeout=30)
        assert got.status_code == 200 and [s["id"] for s in got.json()["sessions"]] == ["s1"]
        auth = {"Authorization": f"Bearer {kitchen}"}
        got = httpx.get(base + "/sessions", headers=auth, timeout=30)
        assert got.status_code == 200 and got.json()["sessions"] == []  # kitchen: its own memory


def test_revoke_takes_the_ids_list_prints_and_the_key_itself(tmp_path) -> None:
    data = str(tmp_path / "mem")
    keys = [
        cli(data, "keys", "create", "--tenant", DEFAULT_TENANT, "--scope", "admin"),
        cli(data, "keys", "create", "--tenant", "kitchen", "--scope", "write"),
    ]
    keys = [out.strip().splitlines()[-1] for out in keys]
    listed = [line.split()[0] for line in cli(data, "keys", "list").strip().splitlines()]
    assert len(listed) == 2 and all(
        k.startswith(f"tk_{i}_") for k, i in zip(keys, listed, strict=True)
    )
    assert f"revoked key {listed[1]}" in cli(data, "keys", "revoke", keys[1])  # the key pasted
    # the default tenant's last live admin key: one line, unless the operator says --last
    out = cli(data, "keys", "revoke", listed[0], code=2)
    assert "last live admin key of the default tenant" in out and "--last" in out
    assert KeyStore(data).verify(keys[0]) is not None
    assert f"revoked key {listed[0]}" in cli(data, "keys", "revoke", listed[0], "--last")
    assert all(KeyStore(data).verify(k) is None for k in keys)
    states = [line.split()[-1] for line in cli(data, "keys", "list").strip().splitlines()]
    assert states == ["revoked", "revoked"]
    assert "no key with id 'nope'" in cli(data, "keys", "revoke", "nope", code=2)
    # revoking every key does not open the store again: its next key may be any key
    cli(data, "keys", "create", "--tenant", "kitchen", "--scope", "read")
