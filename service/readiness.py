"""Store checks for ``/health`` and ``/ready``, and the read-only flag.

``service_problem(state)`` is ``store_problem`` and the store's ``keys`` and ``audit`` tables
(integrity and one row each) and each opened tenant's folder, so damage there is a 503
naming the table or tenant. ``store_problem(memory)`` is cheap: the store's integrity check
(:mod:`tactus_memory.storage.integrity`:
every data file the latest manifests name present and of its recorded size, Lance's own
validation), then the three tables' manifests (row counts) and one row of the items table,
so a missing or truncated file shows up as a reason string instead of a 500 on the next
data route. Reasons never carry a filesystem path (:func:`short` cuts them from Lance's
messages): an HTTP answer must not tell where the store lives.

``store_read_only(settings, memory)``: whether the local store directory cannot be written
(checked once at startup; object stores are assumed writable).
"""

from __future__ import annotations

import os
import re
from typing import Any

from tactus_memory.storage.connect import is_remote_uri, normalise_uri

#: what LanceDB's Python binding raises when a file of the store cannot be read
_LANCE_IO_MARKERS = ("LanceError(IO)", "Not found:", "No such file", "Permission denied")


def is_store_failure(exc: BaseException) -> bool:
    """True for errors that mean 'the store could not be read or written' (not a bug)."""
    if isinstance(exc, OSError):
        return True
    if isinstance(exc, RuntimeError) and str(exc).startswith("lance error"):
        return any(m in str(exc) for m in _LANCE_IO_MARKERS)
    return False


#: an absolute path (POSIX or file://) in an error message: a run of /segments
_PATH = re.compile(r"(?:file://)?(?<![\w.])/?(?:[\w.@~+-]+/){2,}[\w.@~+-]*")


def no_paths(text: str) -> str:
    """``text`` with every filesystem path shortened to its last name (``x/y/z.lance`` ->
    ``z.lance``): error details reach HTTP answers, the store's location must not."""
    return _PATH.sub(lambda m: m.group(0).rstrip("/").rsplit("/", 1)[-1] or "<path>", text)


def short(exc: BaseException, limit: int = 300) -> str:
    """One line of an exception, without LanceDB's Rust source locations or any path."""
    text = " ".join(str(exc).split())
    text = text.split(", /rustc/")[0].split(", /home/")[0]
    return no_paths(text)[:limit]


def store_problem(memory: Any) -> str | None:
    """None when the store is intact and answers (manifests + one row); else what is
    wrong, one line (no path)."""
    store = memory.store
    damage = store.integrity.damage(0)  # probes check now
    if damage:
        return "the store is damaged: " + no_paths("; ".join(map(str, damage[:5])))
    try:
        store.count()  # items manifest
        store.scan(None, ["id", "vector"], limit=1)  # one row: a data file is readable
        store.sense_rows()  # senses table (small)
        store.get_meta("space")  # meta table
    except Exception as exc:  # noqa: BLE001  (any failure is the answer: report it)
        return f"the store cannot be read: {short(exc)}"
    return None


def side_table_problem(name: str, db: Any, storage_options: dict[str, str] | None) -> str | None:
    """None when the root database's ``name`` table (``keys``, ``audit``) is absent, or intact
    and readable (its integrity check and one row); else what is wrong, naming the table."""
    from tactus_memory.storage.integrity import check_table

    try:
        res = db.list_tables()
        if name not in set(getattr(res, "tables", res)):
            return None
        table = db.open_table(name)
        damage = check_table(name, table.uri, storage_options)
        if damage:
            return f"the store's {name} table is damaged: " + no_paths(
                "; ".join(map(str, damage[:3]))
            )
        table.search().limit(1).to_arrow()
    except Exception as exc:  # noqa: BLE001  (any failure is the answer: report it)
        return f"the store's {name} table cannot be read: {short(exc)}"
    return None


def service_problem(state: Any) -> str | None:
    """:func:`store_problem` of the default tenant's store, then the store's ``keys`` and
    ``audit`` tables, then each opened tenant's folder: None when all answer, else the
    first problem, naming the table or the tenant."""
    why = store_problem(state.memory)
    if why is not None:
        return why
    options = state.memory.store.storage_options or None
    keys = state.gate.keys if state.gate is not None else None
    for name, owner in (("keys", keys), ("audit", state.audit)):
        if owner is not None:
            why = side_table_problem(name, owner.db, options)
            if why is not None:
                return why
    for tenant in state.tenants or ():
        why = state.tenants.missing(tenant)
        if why is not None:
            return why
    return None


def store_read_only(uri: str) -> bool:
    """Whether a local store directory exists but cannot be written by this process."""
    if is_remote_uri(uri):
        return False
    path = normalise_uri(uri)  # the store's uri is already normalised: a local path
    return os.path.isdir(path) and not os.access(path, os.W_OK | os.X_OK)
