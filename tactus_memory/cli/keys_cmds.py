"""``tactus keys create|list|revoke`` and ``tactus audit``: who may use a store, and what they
did (:mod:`tactus_memory.storage.keys`, :mod:`tactus_memory.storage.audit`). They open the
store's key and audit tables only: no embedding model is loaded."""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from typing import Annotated

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import ServiceData
from tactus_memory.cli.memory_cmds import _data_dir
from tactus_memory.cli.space_opts import fail
from tactus_memory.storage.keys import SCOPES

keys_app = typer.Typer(
    help="API keys: per tenant, with a scope (read, write, admin), stored hashed in the store.",
    no_args_is_help=True,
)
app.add_typer(keys_app, name="keys")

#: the route the audit log names for the key commands
CLI_ROUTE = "cli: tactus keys {}"
#: who the audit log names for a command run on the store's own machine
CLI_KEY_ID = "operator"
#: the one line that refuses a store's first key when it is not the default tenant's admin
#: key: with no key a server is open; its first key makes every request need one, so it
#: must be the key that keeps the default tenant's data reachable
FIRST_KEY_RULE = (
    "this store has no keys, so servers on it are open; its first key makes every request "
    "need a key, so it must be an admin key of the default tenant: "
    "tactus keys create --tenant {default} --scope admin"
)
#: the one line that refuses to revoke the last live admin key of the default tenant
LAST_ADMIN = (
    "key {key_id} is the last live admin key of the default tenant: without it only the "
    "operator's --token reaches that tenant's data; create another admin key first, or "
    "pass --last"
)


def _stores(data: str | None) -> tuple[object, object]:
    from tactus_memory.storage.audit import AuditLog
    from tactus_memory.storage.keys import KeyStore

    root = _data_dir(data)
    return KeyStore(root), AuditLog(root)


def _when(t: float | None) -> str:
    return "-" if t is None else time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


@keys_app.command("create")
def create(
    tenant: Annotated[str, typer.Option(help="The tenant the key reads and writes.")],
    scope: Annotated[
        str, typer.Option(help=f"One of {', '.join(SCOPES)} (admin may also delete sessions).")
    ] = "read",
    data: ServiceData = None,
    expires: Annotated[
        float | None, typer.Option(help="Days until the key stops working (default: never).")
    ] = None,
    sessions: Annotated[
        str | None,
        typer.Option(help="Only sessions whose id starts with PREFIX (default: every session)."),
    ] = None,
) -> None:
    """Create a key; it is printed once, alone on the last line (only its hash is stored).
    The first key of a tenant brings the tenant into being."""
    from tactus_memory.errors import TactusError
    from tactus_memory.identity import DEFAULT_TENANT

    keys, audit = _stores(data)
    first = not keys.list()  # revoked and expired keys count: a keyed store stays keyed
    if first and (tenant, scope, sessions) != (DEFAULT_TENANT, "admin", None):
        fail(FIRST_KEY_RULE.format(default=DEFAULT_TENANT))
    try:
        key_id, key = keys.create(tenant, scope, expires, sessions=sessions)
    except TactusError as exc:
        fail(str(exc))
    audit.record(CLI_KEY_ID, tenant, CLI_ROUTE.format("create") + f" {key_id}", 0, 1)
    audit.close()
    until = None if expires is None else time.time() + expires * 86400.0
    only = "" if sessions is None else f", sessions {sessions}*"
    typer.echo(f"key {key_id} for tenant {tenant!r}, scope {scope}{only}, expires {_when(until)}")
    if first:
        typer.echo("servers on this store now need a key or the token for every request")
    typer.echo("the key (shown once; store it now):")
    typer.echo(key)


@keys_app.command("list")
def list_keys(
    data: ServiceData = None,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object per key.")] = False,
) -> None:
    """Every key: id, tenant, scope, session prefix, created, expires, revoked, last used
    (never the key)."""
    keys, _ = _stores(data)
    now = time.time()
    for info in keys.list():
        if as_json:
            typer.echo(json.dumps({**asdict(info), "live": info.live(now)}))
            continue
        state = "live" if info.live(now) else ("revoked" if info.revoked else "expired")
        only = "" if info.sessions is None else f"  sessions {info.sessions}*"
        typer.echo(
            f"{info.key_id}  {info.tenant}  {info.scope}{only}  created {_when(info.created)}  "
            f"expires {_when(info.expires)}  last used {_when(info.last_used)}  {state}"
        )


@keys_app.command("revoke")
def revoke(
    key_id: Annotated[
        str, typer.Argument(help="The key's id, as `tactus keys list` prints it (or the key).")
    ],
    data: ServiceData = None,
    last: Annotated[
        bool,
        typer.Option("--last", help="Revoke even the last live admin key of the default tenant."),
    ] = False,
) -> None:
    """Revoke a key: every server refuses it within the read consistency interval. The store
    stays keyed (revoking every key does not open it again)."""
    from tactus_memory.errors import TactusError
    from tactus_memory.identity import DEFAULT_TENANT
    from tactus_memory.storage.keys import KEY_PREFIX

    if key_id.startswith(KEY_PREFIX):  # the key itself, pasted: its id is the part after tk_
        key_id = key_id[len(KEY_PREFIX) :].partition("_")[0]
    keys, audit = _stores(data)
    now = time.time()
    admins = [
        k.key_id
        for k in keys.list()
        if k.live(now) and (k.tenant, k.scope, k.sessions) == (DEFAULT_TENANT, "admin", None)
    ]
    if admins == [key_id] and not last:
        fail(LAST_ADMIN.format(key_id=key_id))
    try:
        info = keys.revoke(key_id)
    except TactusError as exc:
        fail(str(exc))
    audit.record(CLI_KEY_ID, info.tenant, CLI_ROUTE.format("revoke") + f" {key_id}", 0, 1)
    audit.close()
    typer.echo(f"revoked key {key_id} (tenant {info.tenant!r})")


@app.command()
def audit(
    data: ServiceData = None,
    tenant: Annotated[str | None, typer.Option(help="Only this tenant's entries.")] = None,
    limit: Annotated[int, typer.Option(help="The most recent entries to show.")] = 100,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object per entry.")] = False,
) -> None:
    """The audit log: every write, delete and key change (time, key id, tenant, route,
    status, count; never a key or a payload), oldest first."""
    from tactus_memory.errors import TactusError

    _, log = _stores(data)
    try:
        entries = log.entries(tenant=tenant, limit=limit)
    except TactusError as exc:
        fail(str(exc))
    for e in entries:
        if as_json:
            typer.echo(json.dumps(asdict(e)))
        else:
            typer.echo(f"{_when(e.t)}  {e.key_id}  {e.tenant}  {e.route}  {e.status}  {e.count}")
