"""The sense registry: live senses (can embed), senses known only from the store (can be
searched: their vectors and query transform are stored), row counts per sense and each
sense's score calibration. ``Memory`` owns one; nothing else writes the senses table.

Each live sense of a registered class (:mod:`tactus_memory.senses.plugins`) also leaves a record in
the store's meta table (``sense_config:<name>``: its registered name and ``config()``), from
which :meth:`SenseRegistry.restore` rebuilds it after a reopen.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from tactus_memory.errors import (
    InvalidInputError,
    SenseConflictError,
    SenseSwappedError,
    UnknownSenseError,
)
from tactus_memory.names import validate_sense_name
from tactus_memory.results import SenseInfo
from tactus_memory.search.scoring import PROBES, SAMPLE, Calibration, blend, estimate
from tactus_memory.senses.base import Sense, array_to_bytes, bytes_to_array
from tactus_memory.senses.plugins import lookup, registered_name
from tactus_memory.senses.windowed import described_shape
from tactus_memory.spaces.base import Space
from tactus_memory.storage.store import Store
from tactus_memory.vectors import as_unit_rows, vector_column
from tactus_memory.where import SESSION_PREFIX, Where, sessions_under

log = logging.getLogger(__name__)

#: meta key prefix of a sense's record: {"kind": registered name, "config": {...}}
RECORD_KEY = "sense_config:"


class StoredSense(Sense):
    """A sense known only from the store: searchable (vectors are stored), not embeddable."""

    def __init__(
        self,
        name: str,
        modality: str,
        dim: int,
        provenance: dict[str, Any],
        centroid: np.ndarray | None,
    ) -> None:
        self.name = name
        self.modality = modality
        self.dim = dim
        self._provenance = provenance
        self.query_centroid = centroid

    def _not_loaded(self) -> UnknownSenseError:
        return UnknownSenseError(
            f"sense {self.name!r} has rows in this store but is not loaded; call "
            "memory.restore_senses() (rebuilds it from the store's record) or "
            f"memory.add_sense(...) with its encoder to add or embed {self.name!r} items"
        )

    def validate(self, item: Any) -> Any:
        raise self._not_loaded()

    def embed(self, batch: Sequence[Any]) -> np.ndarray:
        raise self._not_loaded()

    def provenance(self) -> dict[str, Any]:
        return dict(self._provenance)


def provenance_of(sense: Sense) -> dict[str, Any]:
    """``sense.provenance()`` as the senses table stores it (JSON round trip)."""
    return json.loads(json.dumps(sense.provenance(), sort_keys=True, default=str))


def _checkpoint(provenance: dict[str, Any]) -> str:
    sha = provenance.get("checkpoint_sha256")
    return f"checkpoint {str(sha)[:12]}" if sha else "another encoder"


def _same_vector(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and bool(np.allclose(a, b))


def _cache_write(write: Any, *args: Any) -> None:
    """Persist a cache (probe embeddings, calibration): best effort, so that searching a
    read-only store works; a failed write only costs recomputing the cache next time."""
    try:
        write(*args)
    except Exception as exc:  # noqa: BLE001  (a cache: any failure is harmless)
        log.warning("could not persist a search cache (read-only store?): %s", exc)


class SenseRegistry:
    """Senses of one memory: live ones, stored ones, row counts and calibrations."""

    def __init__(self, store: Store, space: Space, lock: threading.RLock) -> None:
        self.store = store
        self.space = space
        self.lock = lock
        self._live: dict[str, Sense] = {}
        self._live_prov: dict[str, dict[str, Any]] = {}  # each live sense's provenance
        self._stored: dict[str, StoredSense] = {}
        self._calib: dict[str, Calibration] = {}
        self._counts: dict[str, int] | None = None
        #: the last exact counts plus this process's writes since, and when they were read:
        #: what a search goes by for up to the store's read consistency interval after
        #: another process's commit (or a compaction) dropped the exact ones
        self._recent: dict[str, int] | None = None
        self._recent_at = 0.0
        self._seen_versions: tuple[int, int] = (-1, -1)  # (items, senses) the caches match
        self._probes: np.ndarray | None = None
        self.load()

    def load(self) -> None:
        for row in self.store.sense_rows():
            centroid = None
            if row.get("query_centroid") is not None:
                centroid = bytes_to_array(row["query_centroid"]).astype(np.float32)
            self._stored[row["name"]] = StoredSense(
                row["name"],
                row["modality"],
                int(row["dim"]),
                json.loads(row["provenance"]),
                centroid,
            )
            if row.get("calib_n"):
                self._calib[row["name"]] = Calibration(
                    float(row["mu"]), float(row["sigma"]), int(row["calib_n"])
                )

    @property
    def senses(self) -> dict[str, Sense]:
        """Live senses (can embed new items), name -> Sense."""
        return dict(self._live)

    def add_sense(self, sense: Sense) -> None:
        """Register a live sense. Raises SenseConflictError on a duplicate name or a space or
        dimension mismatch (also against a persisted registration of the same name)."""
        name = validate_sense_name(sense.name)
        with self.lock:
            if name in self._live:
                raise SenseConflictError(f"a sense named {name!r} is already registered")
            sense.bind(self.space)
            stored = self._stored.get(name)
            if stored is not None and (
                stored.dim != sense.dim or stored.modality != sense.modality
            ):
                raise SenseConflictError(
                    f"sense {name!r} is stored as a {stored.modality} sense of dimension "
                    f"{stored.dim}; cannot register a {sense.modality} sense of dimension "
                    f"{sense.dim}"
                )
            centroid = getattr(sense, "query_centroid", None)
            if centroid is not None:
                centroid = np.asarray(centroid, dtype=np.float32).reshape(-1)
            prov_json = json.dumps(sense.provenance(), sort_keys=True, default=str)
            provenance = json.loads(prov_json)
            unchanged = (
                stored is not None
                and stored.provenance() == provenance
                and _same_vector(stored.query_centroid, centroid)
            )
            if stored is not None and not unchanged:
                log.warning("sense %r re-registered with a different encoder", name)
                self._calib.pop(name, None)  # a new encoder: re-estimate the null
            calib = self._calib.get(name)
            if not unchanged:  # reopening with the same sense writes nothing
                self.store.put_sense_row(
                    {
                        "name": name,
                        "modality": sense.modality,
                        "dim": int(sense.dim),
                        "provenance": prov_json,
                        "query_centroid": None if centroid is None else array_to_bytes(centroid),
                        "mu": calib.mu if calib else None,
                        "sigma": calib.sigma if calib else None,
                        "calib_n": calib.n if calib else None,
                        "updated": time.time(),
                    }
                )
            kind = registered_name(sense)
            if kind is not None:
                record = json.dumps({"kind": kind, "config": sense.config()}, sort_keys=True)
                if self.store.get_meta(RECORD_KEY + name) != record:
                    self.store.set_meta(RECORD_KEY + name, record)
            self._stored[name] = StoredSense(name, sense.modality, sense.dim, provenance, centroid)
            self._live[name], self._live_prov[name] = sense, provenance

    def stored_provenance(self, name: str) -> dict[str, Any] | None:
        """The provenance the store records for sense ``name`` (the encoder its stored
        vectors were embedded by), or None when it records no such sense."""
        stored = self._stored.get(name)
        return None if stored is None else stored.provenance()

    def restore(self, skip: Collection[str] = ()) -> dict[str, str]:
        """Rebuild the live senses the store records (each not live yet, but those in
        ``skip``) through the plug-in registry; returns why each sense that could not be
        rebuilt was not (a missing checkpoint, a space without vision, no record)."""
        failed: dict[str, str] = {}
        for name in sorted(self._stored):
            if name in self._live or name in skip:
                continue
            raw = self.store.get_meta(RECORD_KEY + name)
            if raw is None:
                failed[name] = "the store has no record of how to build it"
                continue
            record = json.loads(raw)
            try:
                self.add_sense(
                    lookup("sense", record["kind"]).create(self.space, **record["config"])
                )
            except Exception as exc:  # noqa: BLE001  (reported per sense; it stays searchable)
                failed[name] = f"{type(exc).__name__}: {exc}"
        return failed

    def replace_sense(self, sense: Sense) -> None:
        """Register ``sense`` in place of the sense of its name (live or stored): a new encoder
        for rows already stored (re-embedding). Its provenance and query centroid are
        persisted and the score calibration is re-estimated (if the encoder changed)."""
        with self.lock:
            self._live.pop(validate_sense_name(sense.name), None)
            self.add_sense(sense)

    def check_embedded_by(self, encoders: Collection[Sense]) -> dict[str, SenseSwappedError]:
        """The senses among ``encoders`` (those that embedded the rows about to be committed)
        that the store no longer records: a re-embedding swapped them to another encoder,
        in this process or another (``tactus reembed``). Call it under the write lock, just
        before the commit: the senses and meta tables are re-read at their latest version
        first (one version check each), so a swap committed anywhere before is seen.

        Returns name -> the error to answer those writes with (nothing of them may be
        stored: the store would hold vectors of two encoders). Each swapped live sense is
        rebuilt from the store's record (the new checkpoint) when it can be, so that writes
        prepared from now on embed with the encoder the store records."""
        by_name = {s.name: s for s in encoders}
        if not by_name:
            return {}
        self.store.read_latest_registry()
        self.refresh()
        out: dict[str, SenseSwappedError] = {}
        for name, s in by_name.items():
            stored = self._stored.get(name)
            mine = self._live_prov.get(name) if self._live.get(name) is s else None
            if stored is None or (mine or provenance_of(s)) == stored.provenance():
                continue
            why_not = None
            if self._live.get(name) is s or name not in self._live:
                why_not = self._follow(name)
            now = _checkpoint(stored.provenance())
            then = (
                "the encoder this server now embeds with"
                if why_not is None
                else f"this server could not load it ({why_not}): restart it"
            )
            out[name] = SenseSwappedError(
                f"sense {name!r} was re-embedded to {now} (these rows were embedded by "
                f"{_checkpoint(mine or provenance_of(s))}); nothing was stored, so the store "
                f"does not mix two encoders. Send the write again: {then}"
            )
        return out

    def _follow(self, name: str) -> str | None:
        """Rebuild the live sense ``name`` from the store's record when the store records
        another encoder for it; None when done, else why not."""
        raw = self.store.get_meta(RECORD_KEY + name)
        if raw is None:
            return "the store has no record of how to build it"
        record = json.loads(raw)
        try:
            new = lookup("sense", record["kind"]).create(self.space, **record["config"])
            new.bind(self.space)
        except Exception as exc:  # noqa: BLE001  (reported; the writes are refused either way)
            return f"{type(exc).__name__}: {exc}"
        provenance = provenance_of(new)
        if provenance != self._stored[name].provenance():
            return "its record builds yet another encoder"
        log.warning("sense %r was re-embedded elsewhere; now embedding with its new encoder", name)
        self._live[name], self._live_prov[name] = new, provenance
        return None

    def live_sense(self, name: str) -> Sense:
        validate_sense_name(name)
        if name in self._live:
            return self._live[name]
        if name in self._stored:
            raise self._stored[name]._not_loaded()
        raise UnknownSenseError(f"unknown sense {name!r}; registered: {sorted(self._stored)}")

    def search_sense(self, name: str) -> Sense:
        validate_sense_name(name)
        if name in self._live:
            return self._live[name]
        if name in self._stored:
            return self._stored[name]
        raise UnknownSenseError(f"unknown sense {name!r}; registered: {sorted(self._stored)}")

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows, live or not, with row counts (of the sessions this
        context sees, ``where.SESSION_PREFIX``) and calibration."""
        counts = self.counts() if SESSION_PREFIX.get() is None else self._count_rows()
        out = []
        for name, s in sorted(self._stored.items()):
            c = self._calib.get(name)
            prov = s.provenance()
            out.append(
                SenseInfo(
                    name=name,
                    modality=s.modality,
                    dim=s.dim,
                    provenance=prov,
                    shape=described_shape(self._live.get(name), prov),
                    live=name in self._live,
                    rows=counts.get(name, 0),
                    mu=c.mu if c else None,
                    sigma=c.sigma if c else None,
                    calib_n=c.n if c and c.n else None,
                    calib_final=bool(c and c.final),
                    precision_at_bar=_shipped(self._live.get(name, s), "match_precision"),
                )
            )
        return out

    @contextmanager
    def pinned(self) -> Iterator[None]:
        """One view of the registry for a whole question: the tables' versions are read once
        (:meth:`Store.pinned`), so each step's :meth:`refresh` (the senses in scope, their
        counts and calibrations) compares them without a round trip to LanceDB's event loop
        thread and finds nothing moved."""
        with self.store.pinned():
            self.refresh()
            yield

    def refresh(self) -> None:
        """Drop the row-count cache when the items table moved on (another process's
        commit, a compaction) and reload the stored senses and calibrations when the senses
        table did: replicas agree within the store's read consistency interval. Inside
        :meth:`pinned` the versions are those the question began with."""
        seen = (self.store.version(), self.store.senses_version())
        if seen == self._seen_versions:
            return
        if seen[1] != self._seen_versions[1]:
            # fill copies: other threads may be iterating the current dicts
            self._stored, self._calib = dict(self._stored), dict(self._calib)
            self.load()
        if seen[0] != self._seen_versions[0]:
            self._counts = None
        self._seen_versions = seen

    def note_commit(self, before: int, commits: int = 1) -> None:
        """After this process made ``commits`` commits on top of table version ``before``: the
        count cache stays exact when nobody else committed in between, else it is dropped."""
        if self._seen_versions[0] == before == self.store.version() - commits:
            self._seen_versions = (before + commits, self._seen_versions[1])
        else:
            self._counts = None

    def counts(self, exact: bool = True) -> dict[str, int]:
        """Rows per sense in the whole memory (cached; whatever the context's session prefix).

        ``exact=False`` (a search: which senses have rows, whether a calibration is stale)
        may answer with the counts read at most the store's read consistency interval ago
        plus this process's writes since: the interval in which replicas may already differ.
        Otherwise, with several workers writing one store, every search after another
        worker's commit would recount the whole table, one scan of every fragment
        (benchmarks/capacity.py: search beside writes)."""
        self.refresh()
        counts = self._counts
        if counts is None:
            recent = self._recent
            if (
                not exact
                and recent is not None
                and time.monotonic() < self._recent_at + (self._recount_s())
            ):
                return recent
            with sessions_under(None):
                counts = self._counts = self._count_rows()
            self._recent, self._recent_at = counts, time.monotonic()
        return counts

    def _recount_s(self) -> float:
        interval = self.store.read_consistency
        return 0.0 if interval is None else interval.total_seconds()

    def _count_rows(self) -> dict[str, int]:
        import pyarrow.compute as pc

        vc = pc.value_counts(self.store.scan(None, ["sense"]).column("sense")).to_pylist()
        return {d["values"]: int(d["counts"]) for d in vc}

    def probe_vectors(self) -> np.ndarray:
        """(P, D) embedded probe bank, cached in the store per space."""
        if self._probes is None:
            key = f"probes:{self.space.name}:{len(PROBES)}"
            cached = self.store.get_meta(key)
            if cached is not None:
                arr = np.asarray(json.loads(cached), dtype=np.float32)
            else:
                arr = as_unit_rows(self.space.embed_texts(list(PROBES), query=True), self.space.dim)
                with self.lock:
                    _cache_write(self.store.set_meta, key, json.dumps(arr.round(6).tolist()))
            self._probes = as_unit_rows(arr, self.space.dim)
        return self._probes

    def prior(self, sense: str) -> Calibration | None:
        """A sense's prior calibration (``scoring`` docstring): what the sense ships
        (``calibration_prior()``, a touch checkpoint's), else None (a text sense: none)."""
        row = _shipped(self.search_sense(sense), "calibration_prior")  # {"mu", "sigma"}
        return None if row is None else Calibration(float(row["mu"]), float(row["sigma"]), 0)

    def calibration(self, sense: str) -> Calibration:
        """The null statistics of a sense: its own estimate blended with its prior until final."""
        return blend(self.own_calibration(sense), self.prior(sense))

    def own_calibration(self, sense: str) -> Calibration:
        """Its own estimate (no prior), re-estimated when the row count has doubled."""
        rows = self.counts(exact=False).get(sense, 0)
        calib = self._calib.get(sense, Calibration())
        if not calib.stale(rows):
            return calib
        s = self.search_sense(sense)
        probes = s.query_transform(self.probe_vectors())
        with sessions_under(None):  # the sense's statistics: every session's rows
            sample = self.store.scan(Where().sense(sense).sql(), ["vector"], limit=SAMPLE)
        vecs = vector_column(sample, self.space.dim)
        calib = estimate(probes, vecs, rows)
        self._calib[sense] = calib
        with self.lock:
            row = next((r for r in self.store.sense_rows() if r["name"] == sense), None)
            if row is not None:
                row.update(mu=calib.mu, sigma=calib.sigma, calib_n=calib.n, updated=time.time())
                _cache_write(self.store.put_sense_row, row)
        return calib

    def resolve(self, senses: Sequence[str] | None) -> list[str]:
        if senses is None:
            counts = self.counts(exact=False)
            return [name for name in sorted(self._stored) if counts.get(name, 0) > 0]
        if isinstance(senses, str):
            senses = [senses]
        if not senses:  # as over HTTP (422): an empty list is a mistake, not "search nothing"
            raise InvalidInputError(
                "senses=[] names no sense: pass None (every sense with rows) or at least one name"
            )
        names = []
        for name in senses:
            self.search_sense(name)
            if name not in names:
                names.append(name)
        return names

    def note_writes(
        self, before: int, writes: Sequence[Any], replaced: dict[int, int], commits: int = 1
    ) -> None:
        """After this process committed ``writes`` (``PreparedWrite``; ``replaced``: rows each
        upsert replaced, by ``id(write)``) in ``commits`` commits on top of items version
        ``before``. Never raises: the rows are stored and will be acknowledged; a failure here
        is logged and the counts are re-read when next asked (repaired, not re-committed)."""
        try:
            self.note_commit(before, commits)
            for w in writes:  # rows written (repeats and unchanged rows are not) less replaced
                self.note_write(w.sense.name, w.written - replaced.get(id(w), 0))
        except Exception:  # noqa: BLE001  (a cache: dropped and rebuilt)
            log.exception("bookkeeping after a commit failed; the row counts will be re-read")
            self._counts = None

    def note_write(self, sense: str, n: int) -> None:
        """Keep the cached counts right after a write added n rows to ``sense`` (an upsert's
        new rows: its rows less those it replaced)."""
        if self._recent is not None:
            recent = dict(self._recent)
            recent[sense] = recent.get(sense, 0) + n
            self._recent = recent
        if self._counts is None:
            return
        counts = dict(self._counts)
        counts[sense] = counts.get(sense, 0) + n
        self._counts = counts

    def forget_counts(self) -> None:
        """After a delete (or a write whose count is unknown): recount before the next use."""
        self._counts = self._recent = None


def _shipped(sense: Any, method: str) -> Any:
    """``sense.<method>()`` when the sense has that method (a shipped measurement), else None."""
    return getattr(sense, method, lambda: None)()
