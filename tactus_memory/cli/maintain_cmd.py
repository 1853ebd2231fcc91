"""``tactus maintain``: the one process that maintains a shared store.

Several ``tactus serve --no-maintain`` replicas (and scripts) may write to one store; exactly
one process compacts it, refreshes its indexes and removes old versions
(:mod:`tactus_memory.storage.compaction`), so replicas never compact against each other. The
maintainer needs no embedding model: it opens the store's tables only.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from typing import TYPE_CHECKING, Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import ServiceData
from tactus_memory.cli.memory_cmds import _data_dir
from tactus_memory.cli.progress import RowsBar

if TYPE_CHECKING:
    from tactus_memory.storage.store import Store


@app.command()
def maintain(
    data: ServiceData = None,
    once: Annotated[bool, typer.Option("--once", help="Run one pass and exit.")] = False,
    interval: Annotated[
        float | None,
        typer.Option(help="Seconds between passes (default TACTUS_MAINTAIN_INTERVAL or 10)."),
    ] = None,
    retain: Annotated[
        float | None,
        typer.Option(
            help="Keep versions until superseded this long, seconds (TACTUS_RETAIN_SECONDS, 30)."
        ),
    ] = None,
    passes: Annotated[
        int | None, typer.Option(help="Stop after this many passes (default: run until killed).")
    ] = None,
    check: Annotated[
        bool,
        typer.Option(
            "--check",
            help="Only check the store's integrity (every data file the latest manifests name "
            "present and of its recorded size, Lance's validation): one JSON line per table, "
            "exit 1 when damaged. Changes nothing.",
        ),
    ] = False,
    sense_codes: Annotated[
        bool,
        typer.Option(
            "--sense-codes",
            help="Move a store made before sense codes to the coded layout, in place (every "
            "vector rewritten with its sense's code, the ANN index built again), then exit: "
            "one JSON line per store (rows rewritten, seconds, index rebuilt) on stdout, a bar "
            "with the time left on stderr. A store with "
            "codes already is left as it is. Stop the store's servers first.",
        ),
    ] = False,
    facets: Annotated[
        bool,
        typer.Option(
            "--facets",
            help="Add the touch facet columns (force, area, grip, ...) to a store made before "
            "them, computed from each stored touch window, and embed the windows' captions of "
            "the current caption rule (removing other rules'), then exit: one JSON line per "
            "store. An interrupted run is run again. Stop the store's servers first.",
        ),
    ] = False,
) -> None:
    """Maintain a store: retention (expiry, thinning), size-tiered compaction, incremental
    index refresh, version cleanup.

    Prints one JSON line per pass and table (version, fragments, what was compacted and
    removed), and one for retention when it is configured (items expired and thinned). Run
    exactly one per store; start the servers with ``--no-maintain``. A damaged
    store is never maintained (``--check`` says what is wrong).
    """
    from tactus_memory.errors import TactusError
    from tactus_memory.identity import DEFAULT_TENANT
    from tactus_memory.settings import Settings
    from tactus_memory.storage.audit import tidy
    from tactus_memory.storage.keys import KeyStore
    from tactus_memory.storage.store import Store
    from tactus_memory.storage.tenants import tenant_names, tenant_uri

    location = _data_dir(data)
    given = {"maintain": True}
    if interval is not None:
        given["maintain_interval"] = interval
    if retain is not None:
        given["retain_seconds"] = retain
    try:
        cfg = Settings(**given).maintenance()
        store = Store(location, maintenance=cfg, tenant=DEFAULT_TENANT)
        # every tenant's database too (storage/tenants.py), each maintained as the root is
        named = {key.tenant for key in KeyStore(location).list()}
        names = tenant_names(location, named)
        others = [Store(tenant_uri(location, t), maintenance=cfg, tenant=t) for t in names[1:]]
        stores = [store, *(s for s in others if s.exists)]
    except (TactusError, ValueError, OSError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    if not store.exists:
        typer.echo(f"error: no memory at {location!r} (no items table)", err=True)
        raise typer.Exit(2)
    if check:
        raise typer.Exit(max(_check(s) for s in stores))
    if sense_codes:
        raise typer.Exit(max(_sense_codes(s, s is store) for s in stores))
    if facets:
        raise typer.Exit(max(_facets(s, s is store) for s in stores))
    typer.echo(
        f"maintaining {store.uri} every {cfg.maintain_interval:g}s "
        f"(retain {cfg.retain_seconds:g}s, fan-in {cfg.fan_in})",
        err=True,
    )
    done = 0
    try:
        while True:
            t0 = time.monotonic()
            try:
                # a pass compacts inline; cleanup runs in its own thread (every
                # cleanup_interval) unless this is the only pass
                for one in stores:
                    one.maintain(force=True, wait=once)
                    where = {} if one is store else {"tenant": one.retention.tenant}
                    tables = one.maintainer().tables
                    for report in one.last_maintenance:
                        t = tables[report.table.removesuffix(".lance")]
                        totals = {
                            "versions_removed_total": t.versions_removed_total,
                            "bytes_removed_total": t.bytes_removed_total,
                        }
                        typer.echo(json.dumps({"pass": done, **where, **asdict(report), **totals}))
                    if one.retention.enabled():
                        retention = asdict(one.retention.report)
                        typer.echo(json.dumps({"pass": done, **where, "retention": retention}))
                tidy(store.db, cfg.retain_seconds)  # the key and audit tables
            except Exception as exc:  # noqa: BLE001  (a conflict or a transient store error:
                # logged, retried next pass; the maintainer must keep running)
                typer.echo(f"maintenance pass failed (retried): {exc}", err=True)
            done += 1
            if once or (passes is not None and done >= passes):
                break
            time.sleep(max(0.0, cfg.maintain_interval - (time.monotonic() - t0)))
    except KeyboardInterrupt:
        pass
    for one in stores:
        one.wait_for_cleanup(60)


def _check(store: Store) -> int:
    """``--check``: print each table's verdict (one JSON line); 1 when any is damaged."""
    from tactus_memory.storage.integrity import check_table

    damaged = False
    for name, uri in store.table_uris().items():
        damage = check_table(name, uri, store.storage_options)
        damaged |= bool(damage)
        verdict = {"table": name, "ok": not damage, "damage": [d.detail for d in damage]}
        typer.echo(json.dumps(verdict))
    typer.echo(
        f"{store.uri}: DAMAGED (writes are refused; restore the files named above from a backup)"
        if damaged
        else f"{store.uri}: intact",
        err=True,
    )
    return 1 if damaged else 0


def _sense_codes(store: Store, root: bool) -> int:
    """``--sense-codes``: migrate one store (:mod:`tactus_memory.storage.migrate`) and print
    its report (one JSON line); 1 when it failed."""
    from tactus_memory.storage.migrate import add_sense_codes

    where = {} if root else {"tenant": store.retention.tenant}
    try:
        # a coded store is left as it is: nothing to count
        with RowsBar(f"sense codes {store.uri}", 0 if store.codes() else store.count()) as bar:
            report = add_sense_codes(store, on_batch=bar)
    except Exception as exc:  # noqa: BLE001  (reported; every store is tried)
        typer.echo(
            f"{store.uri}: sense codes not added: {exc} (run it again with the store's "
            "servers stopped: it finishes or redoes what was left)",
            err=True,
        )
        return 1
    typer.echo(json.dumps({**where, **report.as_dict()}))
    return 0


def _facets(store: Store, root: bool) -> int:
    """``--facets``: add the facet columns to one store
    (:mod:`tactus_memory.storage.facet_backfill`) and rebuild its caption embeddings, one
    JSON line; 1 when the facets failed, 2 when the captions did (one line on stderr, the
    JSON says ``captions_error``)."""
    from tactus_memory.storage.facet_backfill import add_facets

    where = {} if root else {"tenant": store.retention.tenant}
    try:
        with RowsBar(f"facets {store.uri}", store.count()) as bar:
            report = add_facets(store, on_batch=bar)
    except Exception as exc:  # noqa: BLE001  (reported; every store is tried)
        typer.echo(f"{store.uri}: facets not added: {exc} (run it again)", err=True)
        return 1
    try:
        captions: dict[str, Any] = _captions(store)
    except Exception as exc:  # noqa: BLE001  (the facets are in; the captions said apart)
        line = " ".join(str(exc).split())  # one line, whatever the error's text
        typer.echo(f"error: {store.uri}: captions not embedded: {line} (run it again)", err=True)
        typer.echo(json.dumps({**where, **report.as_dict(), "captions_error": line}))
        return 2
    typer.echo(json.dumps({**where, **report.as_dict(), **captions}))
    return 0


def _captions(store: Store) -> dict[str, int]:
    """The store's caption embeddings rebuilt in its recorded space
    (:meth:`tactus_memory.search.captions.Captions.rebuild`)."""
    from tactus_memory.search.captions import Captions
    from tactus_memory.spaces.resolve import recorded_space, resolve_space

    space = resolve_space(recorded=recorded_space(store.get_meta("space")))
    return Captions(store, space).rebuild()
