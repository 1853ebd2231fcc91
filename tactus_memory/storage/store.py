"""LanceDB storage: schema, safely built filters, indexes and compaction.

One store is one LanceDB database (a directory or an object-storage prefix) with three tables:

``items``  one row per remembered thing (any sense), the columns in :func:`items_schema`::

    id str | session str | sense str | t float64 | t_end float64
    vector fixed_size_list<float32>[D + 16] | meta str (JSON) | text str? | raw binary? (npy bytes)
    source str | episode int64? | created float64

(``vector``: the D embedding, then its sense's code, which sets each sense's rows apart in
the ANN index: :mod:`tactus_memory.storage.codes`; every read returns the D embedding
columns only; a store made before codes keeps D.)

``senses`` one row per sense ever registered: name, modality, dim, provenance (JSON), an
           optional ``query_centroid`` (npy bytes) and the score calibration (mu, sigma, calib_n).
``meta``   key/value strings: the space (name, dim) the store was created with, cached probe
           embeddings, index bookkeeping.

Filters: every SQL ``WHERE`` fragment is built by :class:`~tactus_memory.where.Where` from
validated values (ids and sense names by regex, finite numbers; literals quote-escaped).
Every read of the items (scan, count, vector search) and every delete ANDs the session prefix
of its context (``where.SESSION_PREFIX``: a key limited to sessions) into its filter.

Indexes: :class:`IndexConfig` (scalar indexes from 10k rows, an IVF_SQ cosine index from 20k,
retrained after 4x growth or 8 deltas; selective filters scan flat). Compaction, index
refresh and version retention follow :mod:`tactus_memory.storage.compaction`, run by the process
that owns maintenance, after ``compact_every`` commits of any one table (items, senses, meta:
each counted on its own). Every write first passes the integrity check
(:mod:`tactus_memory.storage.integrity`). Connections re-read the latest version every
``read_consistency`` seconds (:mod:`tactus_memory.storage.connect`), so replicas see each other.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from datetime import timedelta
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import SpaceMismatchError
from tactus_memory.limits import DEFAULT_READ_CONSISTENCY_S
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.storage.codes import CODE_DIMS, codes_of, strip_table
from tactus_memory.storage.compaction import Maintainer, TableReport, fragment_infos
from tactus_memory.storage.connect import normalise_uri, storage_options_for
from tactus_memory.storage.connect import read_consistency_interval as consistency_from
from tactus_memory.storage.indexes import StoreIndexes
from tactus_memory.storage.integrity import IntegrityWatch, check_store
from tactus_memory.storage.passes import PASSES_KEPT, MaintenancePass, announce_commit, record_pass
from tactus_memory.storage.retention import Erasure, Retention
from tactus_memory.storage.tables import IndexConfig, items_schema, meta_schema, senses_schema
from tactus_memory.storage.threads import start_background
from tactus_memory.where import Where, _sql_str, sessions_under, within_sessions

if TYPE_CHECKING:  # heavy imports stay lazy
    import pyarrow as pa
    from lancedb.table import Table

log = logging.getLogger(__name__)

#: (table name, id of its handle) -> its version, as first read inside Store.pinned (None:
#: not pinned); keyed by the handle too, so two stores (tenants) in one context never share
_PINNED: ContextVar[dict[tuple[str, int], int] | None] = ContextVar(
    "tactus_pinned_versions", default=None
)


def pinned_version(name: str, table: Any) -> int:
    """``table``'s version: asked of LanceDB, or as first asked in this pinned context."""
    seen = _PINNED.get()
    if seen is None:
        return int(table.version)
    key = (name, id(table))
    if key not in seen:
        seen[key] = int(table.version)
    return seen[key]


ITEMS = "items"
SENSES = "senses"
META = "meta"
#: the session trajectories (:mod:`tactus_memory.storage.posestore`)
POSES = "poses"


def _upsert(table: Table, key: str, data: pa.Table) -> None:
    """One merge-insert commit on ``key``: matching rows replaced, the others inserted."""
    table.merge_insert(key).when_matched_update_all().when_not_matched_insert_all().execute(data)


# --------------------------------------------------------------------------- store
class Store(StoreIndexes):
    """One LanceDB connection; writes are serialised by the Memory's lock. Its indexes:
    :class:`~tactus_memory.storage.indexes.StoreIndexes`."""

    def __init__(
        self,
        uri: str,
        *,
        storage_options: dict[str, str] | None = None,
        read_consistency_interval: timedelta | float | None = DEFAULT_READ_CONSISTENCY_S,
        index: IndexConfig | None = None,
        maintenance: MaintenanceConfig | None = None,
        tenant: str | None = None,
    ) -> None:
        """``read_consistency_interval``: how stale reads may be against other processes'
        commits (seconds, default 1 s; None: never re-read);
        ``storage_options``: object-store options (``connect.storage_options_for``);
        ``maintenance``: the policy, and whether this process runs it (default: the policy's
        defaults; the memory passes the configured one, storage reads no settings);
        ``tenant``: whose store this is, for the retention rules naming a tenant."""
        import lancedb

        self.uri = normalise_uri(uri)
        self.index = index or IndexConfig()
        self.maintenance = maintenance or MaintenanceConfig()
        self.storage_options = storage_options_for(self.uri, storage_options)
        self.read_consistency = consistency_from(read_consistency_interval)
        self.db = lancedb.connect(
            self.uri,
            storage_options=self.storage_options or None,
            read_consistency_interval=self.read_consistency,
        )
        self._maintainer: Maintainer | None = None
        #: this process's item commits and compaction commits take turns (no self-conflicts)
        self.commit_lock = threading.Lock()
        self._cleanup_thread: threading.Thread | None = None
        self._last_cleanup = -math.inf
        #: what the last maintenance run did, per table
        self.last_maintenance: list[TableReport] = []
        self.passes: deque[MaintenancePass] = deque(maxlen=PASSES_KEPT)
        self._items: Any = None
        self._senses: Any = None
        self._meta: Any = None
        self._maintenance = threading.Lock()
        #: commits per table since maintenance last ran (each table is due on its own)
        self._commits: dict[str, int] = {}
        #: called after every commit of any table (Memory schedules its maintenance there)
        self.on_commit: Callable[[], None] | None = None
        self._busy: int | None = None  # the thread running maintain()
        self.integrity = IntegrityWatch(
            lambda: check_store(self.table_uris(), self.storage_options)
        )
        self._schema: pa.Schema | None = None
        self._indexed = False
        self._scalar_indexed = False
        self._partitions: int | None = None
        self._probes = self._sense_probes = None
        #: expiry and thinning, and the erasure of deleted rows, run by maintenance
        #: (:mod:`tactus_memory.storage.retention`)
        self.retention = Retention(self, tenant)
        self.erasure = Erasure()
        self._other_uris: dict[str, str] = {}
        self._open_existing()

    # ----------------------------------------------------------- tables
    def _table_names(self) -> set[str]:
        res = self.db.list_tables()
        names = getattr(res, "tables", res)
        return set(names)

    def _open_existing(self) -> None:
        names = self._table_names()
        if ITEMS in names:
            self._items = self.db.open_table(ITEMS)
        if SENSES in names:
            self._senses = self.db.open_table(SENSES)
        if META in names:
            self._meta = self.db.open_table(META)

    @property
    def exists(self) -> bool:
        """Whether the store has its items table (a memory was created here)."""
        return self._items is not None

    @property
    def items(self) -> Any:
        if self._items is None:
            raise RuntimeError("store has no items table yet; call bind_space first")
        return self._items

    @property
    def schema(self) -> pa.Schema:
        """The items table's schema (cached: reading it is a LanceDB round trip)."""
        if self._schema is None:
            self._schema = self.items.schema
        return self._schema

    def bind_space(self, name: str, dim: int, fingerprint: str | None = None) -> None:
        """Record the space (name, dim, model fingerprint; never its folder) on creation; on
        reopen raise SpaceMismatchError if it differs. A store recorded without a fingerprint
        gets the first one it is opened with."""
        if self._meta is None:
            self._meta = self.db.create_table(META, schema=meta_schema(), exist_ok=True)
        stored = self.get_meta("space")
        record = {"name": name, "dim": int(dim)}
        if fingerprint:
            record["fingerprint"] = fingerprint
        if stored is not None:
            info = json.loads(stored)
            if info["name"] != name or int(info["dim"]) != int(dim):
                raise SpaceMismatchError(
                    f"this memory was created with space {info['name']!r} (dim {info['dim']}), "
                    f"but was opened with space {name!r} (dim {dim}); open it with "
                    f"{info['name']!r} or use another directory"
                )
            known = info.get("fingerprint")
            if known and fingerprint and known != fingerprint:
                raise SpaceMismatchError(
                    f"this memory was created with the {name!r} model fingerprinted {known}, "
                    f"but was opened with a model folder fingerprinted {fingerprint}; open it "
                    "with the folder it was created with"
                )
            if fingerprint and not known:
                self.set_meta("space", json.dumps(record))
        else:
            self.set_meta("space", json.dumps(record))
        if self._items is None:
            # Lance file format 2.1: ~1.5x faster random access to the hit columns than 2.0
            # (measured at 1M rows, benchmarks/README.md)
            self._items = self.db.create_table(
                ITEMS,
                schema=items_schema(dim, CODE_DIMS),
                exist_ok=True,
                storage_options={**self.storage_options, "new_table_data_storage_version": "2.1"},
            )
        if self._senses is None:
            self._senses = self.db.create_table(SENSES, schema=senses_schema(), exist_ok=True)

    # ----------------------------------------------------------- meta
    def get_meta(self, key: str) -> str | None:
        if self._meta is None:
            return None
        rows = self._meta.search().where(f"key = {_sql_str(key)}").limit(1).to_arrow()
        return None if rows.num_rows == 0 else rows.column("value")[0].as_py()

    def set_meta(self, key: str, value: str) -> None:
        self.set_meta_many({key: value})

    def set_meta_many(self, values: dict[str, str]) -> None:
        """Upsert meta keys, in one commit."""
        import pyarrow as pa

        self.integrity.require()
        data = pa.table({"key": [*values], "value": [*values.values()]}, schema=meta_schema())
        _upsert(self._meta, "key", data)
        self._committed(META)

    def delete_meta(self, key: str) -> None:
        self.integrity.require()
        self._meta.delete(f"key = {_sql_str(key)}")
        self._committed(META)

    def meta_items(self, prefix: str) -> dict[str, str]:
        """Every meta key starting with ``prefix`` (a literal: no ``%`` or ``_``) -> value."""
        if self._meta is None:
            return {}
        rows = self._meta.search().where(f"key LIKE {_sql_str(prefix + '%')}").limit(None)
        return {r["key"]: r["value"] for r in rows.to_arrow().to_pylist()}

    def set_episodes(self, ids: Sequence[str], episodes: np.ndarray) -> None:
        """Write the ``episode`` column of the rows ``ids`` (an (N,) int array) in one commit."""
        import pyarrow as pa

        self.integrity.require()
        data = pa.table({"id": list(ids), "episode": pa.array(episodes, pa.int64())})
        self.items.merge_insert("id").when_matched_update_all().execute(data)
        self._committed(ITEMS)

    # ----------------------------------------------------------- senses registry
    def sense_rows(self) -> list[dict[str, Any]]:
        if self._senses is None:
            return []
        return self._senses.search().limit(None).to_arrow().to_pylist()

    def put_sense_row(self, row: dict[str, Any]) -> None:
        import pyarrow as pa

        self.integrity.require()
        data = pa.Table.from_pylist([row], schema=senses_schema())
        _upsert(self._senses, "name", data)
        self._committed(SENSES)

    def _committed(self, table: str) -> None:
        announce_commit()
        self._commits[table] = self._commits.get(table, 0) + 1
        if self.on_commit is not None and self._busy != threading.get_ident():
            self.on_commit()  # (not from maintenance's own commits: it would wait for itself)

    def table_uris(self) -> dict[str, str]:
        """name -> URI of each table of the memory the store has (items, senses, meta, and
        poses once a trajectory was written): each is checked, compacted and cleaned up."""
        tables = ((ITEMS, self._items), (SENSES, self._senses), (META, self._meta))
        uris = {name: tbl.uri for name, tbl in tables if tbl is not None}
        if POSES not in self._other_uris and POSES in self._table_names():
            self._other_uris[POSES] = self.db.open_table(POSES).uri
        return uris | self._other_uris

    # ----------------------------------------------------------- writes
    def write(self, data: pa.Table, *, upsert: bool) -> None:
        """One LanceDB commit: append, or merge-insert on ``id`` (idempotent upsert). A commit
        that raises may still have landed (a lost reply): it is retried once as a merge-insert
        on ``id``, so the rows are stored once either way, never twice."""
        self.integrity.require()
        with self.commit_lock:
            try:
                if upsert:
                    _upsert(self.items, "id", data)
                else:
                    self.items.add(data)
            except Exception as exc:  # noqa: BLE001  (retried idempotently, else raised)
                log.warning("a commit failed (%s); retried once as a merge-insert on id", exc)
                _upsert(self.items, "id", data)
        self._committed(ITEMS)

    def rows_by_id(self, ids: Sequence[str], columns: Sequence[str] = ()) -> dict[str, Any]:
        """The stored rows of ``ids`` (any session's: ids are the tenant's) by id: ``id``,
        ``session``, ``sense`` and ``columns``, in one scan."""
        if self._items is None or not ids:
            return {}
        wanted = list(dict.fromkeys(["id", "session", "sense", *columns]))
        with sessions_under(None):  # ids are the tenant's: a prefix key may not reuse one
            rows = self.scan(Where().ids(list(ids)).sql(), wanted).to_pylist()
        return {row["id"]: row for row in rows}

    def delete(self, where: str) -> None:
        self.integrity.require()
        where = within_sessions(where) or where
        with self.commit_lock:
            self.items.delete(where)
            self.erasure.note_delete()
        self._committed(ITEMS)

    def count(self, where: str | None = None) -> int:
        return 0 if self._items is None else int(self.items.count_rows(within_sessions(where)))

    # ----------------------------------------------------------- reads
    def scan(self, where: str | None, columns: Sequence[str], limit: int | None = None) -> pa.Table:
        q = self.items.search()
        where = within_sessions(where)
        if where:
            q = q.where(where)
        return strip_table(q.select(self.present(columns)).limit(limit).to_arrow(), self.dim())

    def present(self, columns: Sequence[str]) -> list[str]:
        """``columns`` the items table has (a store made before places, opened where it
        cannot be written, has no place columns: its items read as unplaced)."""
        return [c for c in columns if c in self.schema.names]

    # ----------------------------------------------------------- indexes & compaction
    def dim(self) -> int:
        """The embeddings' dimension D (the stored vectors may carry sense codes after it)."""
        return int(self.schema.field("vector").type.list_size) - self.codes()

    def codes(self) -> int:
        """Sense-code dimensions after each stored embedding (:mod:`.codes`; 0: made before)."""
        return codes_of(self.schema.field("vector"))

    def version(self) -> int:
        """The items table's version as this connection sees it (ours and others' commits);
        inside :meth:`pinned`, as it was first asked there."""
        return 0 if self._items is None else pinned_version(ITEMS, self.items)

    def senses_version(self) -> int:
        return 0 if self._senses is None else pinned_version(SENSES, self._senses)

    @contextmanager
    def pinned(self) -> Iterator[None]:
        """One read of each table's version for a whole question (a read only: a search),
        in this context and the threads it hands its context to (the ANN queries): each ask
        is a round trip to LanceDB's event loop thread, 4 of a search's 5 without it."""
        token = _PINNED.set({}) if _PINNED.get() is None else None
        try:
            yield
        finally:
            if token is not None:
                _PINNED.reset(token)

    def meta_version(self) -> int:
        """The meta table's version (caches of meta records key on it)."""
        return 0 if self._meta is None else int(self._meta.version)

    def read_latest(self) -> None:
        """Every table at its latest version now: read-your-writes across ``--workers``."""
        for table in (self._items, self._senses, self._meta):
            if table is not None:
                table.checkout_latest()

    def read_latest_registry(self) -> None:
        """The senses and meta tables at their latest version now (other processes' commits,
        not only within the read consistency interval): a sense swap check."""
        for table in (self._senses, self._meta):
            if table is not None:
                table.checkout_latest()

    def maintainer(self) -> Maintainer:
        """The maintenance runner for this store's tables (built on first use)."""
        if self._maintainer is None or set(self._maintainer.tables) != set(self.table_uris()):
            self._maintainer = Maintainer(
                self.table_uris(), self.storage_options, self.maintenance, self.commit_lock
            )
        return self._maintainer

    def maintain(self, *, force: bool = False, wait: bool | None = None) -> bool:
        """Build/retrain indexes past the threshold, then run the maintenance policy
        (:mod:`tactus_memory.storage.compaction`) on every table; True when something ran. Only the
        owner of maintenance runs it unless ``force``; never on a damaged store. Writes may go
        on meanwhile. Version cleanup runs in its own thread at most every
        ``cleanup_interval`` seconds; ``wait`` (default: ``force``) runs it now and waits.
        """
        wait = force if wait is None else wait
        if not (force or self.maintenance.maintain):
            return False
        damage = self.integrity.damage(0)
        if damage:  # a cleanup could remove the older versions a repair needs
            log.error("the store is damaged, maintenance skipped: %s", "; ".join(map(str, damage)))
            return False
        if not self._maintenance.acquire(blocking=force):
            return False
        self._busy = threading.get_ident()
        start = time.time()
        try:
            cfg = self.index
            n = self.count()
            if cfg.scalar_threshold <= n < cfg.threshold and not self.has_scalar_indexes():
                self.build_scalar_indexes()
            if n >= cfg.threshold:
                info = json.loads(self.get_meta("index") or "{}")
                grown = n >= cfg.retrain_growth * int(info.get("rows", n))
                if not self.has_vector_index() or grown or self.vector_deltas() > cfg.max_deltas:
                    self.build_indexes()
            self._commits = {}
            try:
                self.retention.run()  # its deletes are compacted away just below
            except Exception:  # noqa: BLE001  (retried next pass; compaction goes on)
                log.exception("retention failed; it will be retried")
            deletes = self.erasure.deletes
            maintainer = self.maintainer()
            reports = maintainer.run(cleanup=False)
            if self._items is not None and self.maintenance.erase_deleted:  # else never erased
                left = sum(f.deleted for f in fragment_infos(self.items.to_lance()))
                self.erasure.note_compacted(deletes, left)
            for tbl in (self._items, self._senses, self._meta):
                if tbl is not None:  # our handles must not stay on versions cleanup removes
                    tbl.checkout_latest()
            if wait:
                self.wait_for_cleanup()
                self._cleanup(reports)
                self._last_cleanup = time.monotonic()
            else:
                self._start_cleanup()
            self.last_maintenance = reports
            for report in reports:
                log.debug("maintenance: %s", report)
            return True
        finally:
            self._busy = None
            record_pass(self.passes, start)  # under the lock: this process's never overlap
            self._maintenance.release()

    def _start_cleanup(self) -> None:
        busy = self._cleanup_thread is not None and self._cleanup_thread.is_alive()
        due = time.monotonic() - self._last_cleanup >= self.maintenance.cleanup_interval
        if busy or not due:
            return
        self._last_cleanup = time.monotonic()
        self._cleanup_thread = start_background(self._cleanup_quietly, "tactus-cleanup")

    def _cleanup_quietly(self) -> None:
        try:
            self._cleanup(None)
        except Exception:  # noqa: BLE001  (retried on the next run)
            log.exception("version cleanup failed; it will be retried")

    def _cleanup(self, reports: list[TableReport] | None) -> None:
        started = time.time()
        self.maintainer().cleanup(reports)
        self.erasure.note_cleanup(started, self.maintenance.retain_seconds)

    def wait_for_cleanup(self, timeout: float | None = None) -> None:
        if self._cleanup_thread is not None:
            self._cleanup_thread.join(timeout)

    def needs_maintenance(self) -> bool:
        """Whether some table (each counted on its own) had ``compact_every`` commits, deleted
        rows wait to be erased, or retention is due."""
        due = max(self._commits.values(), default=0) >= self.index.compact_every
        erase = self.erasure.due(self.maintenance.retain_seconds)
        due = due or erase or self.retention.due()  # work without new commits
        return self.maintenance.maintain and due
