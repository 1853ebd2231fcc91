"""Memory: one LanceDB store, one embedding space, many senses, searchable in language.

```python
memory = Memory.open("./memory")                 # default space: MiniLM
memory.add("s1", "text", "put the mug on the shelf", t=3.0, meta={"by": "operator"})
hits = memory.search("holding a mug", k=5, senses=["text", "touch"], session="s1")
```

Writes: items are validated and embedded *before* anything is written, then written in one
LanceDB commit (all-or-nothing) under a lock. ``id=`` / ``ids=`` make a write an idempotent
upsert (merge-insert on ``id``). Maintenance (ANN index past a row threshold, compaction of
small appends) runs in a background daemon thread; unindexed rows are still searched (flat).

Search: the query is embedded once by the space, then for each sense searched it passes the
sense's query transform, runs a prefiltered ANN search restricted to that sense, and hit
cosines are calibrated into z-scores (see :mod:`tactus_memory.scoring`) so senses merge
fairly. Time filters use overlap semantics: an item spanning ``[t, t_end]`` matches
``after``/``before`` when ``t_end >= after`` and ``t <= before``.

Senses: "text" is registered on open. Other live senses must be re-added after a reopen, but
their registration (name, modality, dim, provenance, optional ``query_centroid``, score
calibration) is persisted, so a sense with rows can be *searched* without its live object:
its query transform is rebuilt from the stored centroid (``q - c``, renormalised). A sense
object that exposes ``query_centroid`` (a (D,) array) must use exactly that transform.

Extension points (temporal operators and the service build on these, not on LanceDB):
``Where`` (validated filter builder: session/senses/ids/source/episode/overlaps/t_range),
``Memory._query(q, k, senses, where, transform=..., build=...)`` (the one ranked search
path), ``Memory.store.scan(where, columns, limit)`` (unranked reads), ``Memory.calibration``.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from datetime import timedelta
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from tactus_memory.errors import (
    InvalidInputError,
    NotFoundError,
    SenseConflictError,
    UnknownSenseError,
)
from tactus_memory.scoring import PROBES, SAMPLE, Calibration, estimate
from tactus_memory.senses import (
    MAX_TEXT_CHARS,
    Sense,
    TextSense,
    array_to_bytes,
    bytes_to_array,
    validate_sense_name,
)
from tactus_memory.spaces.base import Space
from tactus_memory.store import (
    HIT_COLUMNS,
    IndexConfig,
    Store,
    Where,
    finite_float,
    validate_id,
    validate_source,
)
from tactus_memory.temporal import TemporalMixin
from tactus_memory.vectors import as_unit_rows

log = logging.getLogger(__name__)

MAX_K = 1000
MAX_META_BYTES = 65_536
MAX_BATCH = 100_000


# --------------------------------------------------------------------------- result models
class Hit(BaseModel):
    """One search result. ``score`` is the calibrated z-score, ``cosine`` the raw cosine."""

    id: str
    session: str
    sense: str
    t: float
    t_end: float
    score: float
    cosine: float
    meta: dict[str, Any] = Field(default_factory=dict)
    text: str | None = None
    source: str = ""
    episode: int | None = None


class Item(BaseModel):
    """One stored row, with ``raw`` decoded by its sense (array or text) when possible."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    id: str
    session: str
    sense: str
    t: float
    t_end: float
    meta: dict[str, Any] = Field(default_factory=dict)
    text: str | None = None
    raw: Any = None
    source: str = ""
    episode: int | None = None
    created: float
    vector: list[float] | None = None


class SessionSummary(BaseModel):
    """Counts per sense and the time span of one session."""

    id: str
    n: int
    counts: dict[str, int]
    t_min: float
    t_max: float


class SenseInfo(BaseModel):
    """A sense registered in the store (live or persisted only)."""

    name: str
    modality: str
    dim: int
    provenance: dict[str, Any]
    live: bool
    rows: int
    mu: float | None = None
    sigma: float | None = None


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
            f"sense {self.name!r} has rows in this store but is not loaded; "
            f"call memory.add_sense(...) with its encoder to add or embed {self.name!r} items"
        )

    def validate(self, item: Any) -> Any:
        raise self._not_loaded()

    def embed(self, batch: Sequence[Any]) -> np.ndarray:
        raise self._not_loaded()

    def query_transform(self, queries: np.ndarray) -> np.ndarray:
        if self.query_centroid is None:
            return queries
        return as_unit_rows(queries - self.query_centroid[None, :], self.dim, what="query")

    def provenance(self) -> dict[str, Any]:
        return dict(self._provenance)


# --------------------------------------------------------------------------- helpers
def _same_vector(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and bool(np.allclose(a, b))


def _check_k(k: Any) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_K:
        raise InvalidInputError(f"k must be an int in [1, {MAX_K}], got {k!r}")
    return int(k)


def _meta_json(meta: Any) -> str:
    if meta is None:
        return "{}"
    if not isinstance(meta, dict) or not all(isinstance(key, str) for key in meta):
        raise InvalidInputError("meta must be a dict with string keys")
    try:
        out = json.dumps(meta, allow_nan=False, sort_keys=True, ensure_ascii=False)
        size = len(out.encode())
    except UnicodeEncodeError:
        raise InvalidInputError(
            "meta contains a lone surrogate (e.g. '\\udfff'), which is not valid Unicode"
        ) from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"meta is not JSON-serialisable: {exc}") from None
    if size > MAX_META_BYTES:
        raise InvalidInputError(f"meta is larger than {MAX_META_BYTES} bytes as JSON")
    return out


def _per_item(value: Any, n: int, what: str) -> list[Any]:
    """A list of n values, or a scalar/None broadcast to n."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise InvalidInputError(f"{what} has {len(value)} entries for {n} items")
        return list(value)
    return [value] * n


def _check_query_text(query: Any) -> str:
    if not isinstance(query, str) or not query.strip():
        raise InvalidInputError("query must be a non-empty string")
    if len(query) > MAX_TEXT_CHARS:
        raise InvalidInputError(f"query has {len(query)} characters, limit {MAX_TEXT_CHARS}")
    return query


def _cache_write(write: Any, *args: Any) -> None:
    """Persist a cache (probe embeddings, calibration): best effort, so that searching a
    read-only store works; a failed write only costs recomputing the cache next time."""
    try:
        write(*args)
    except Exception as exc:  # noqa: BLE001  (a cache: any failure is harmless)
        log.warning("could not persist a search cache (read-only store?): %s", exc)


# --------------------------------------------------------------------------- memory
class Memory(TemporalMixin):
    """A robot memory: items of every sense in one LanceDB table, one embedding space.

    Use :meth:`open`. Thread-safe: writes are serialised by a lock, reads run concurrently.
    """

    def __init__(self, store: Store, space: Space, *, background: bool = True) -> None:
        self.store = store
        self.space = space
        self.background = background
        self._lock = threading.RLock()
        self._live: dict[str, Sense] = {}
        self._stored: dict[str, StoredSense] = {}
        self._calib: dict[str, Calibration] = {}
        self._counts: dict[str, int] | None = None
        self._probes: np.ndarray | None = None
        self._maint_thread: threading.Thread | None = None
        store.bind_space(space.name, int(space.dim))
        self._load_registry()
        self.add_sense(TextSense(space))

    # ----------------------------------------------------------- construction
    @classmethod
    def open(
        cls,
        path: str = "./memory",
        space: Space | None = None,
        *,
        storage_options: dict[str, str] | None = None,
        index: IndexConfig | None = None,
        index_threshold: int | None = None,
        read_consistency_interval: timedelta | None = None,
        background: bool = True,
    ) -> Memory:
        """Open (or create) a memory at ``path``: a local directory, ``file://``, or an
        object-storage URI (``s3://``, ``gs://``, ``az://``) with ``storage_options``.

        ``space`` defaults to the space the store records (MiniLM, ``get_space("minilm")``, for
        a new store); a store created with another space raises
        :class:`~tactus_memory.errors.SpaceMismatchError` naming both.
        """
        cfg = index or IndexConfig()
        if index_threshold is not None:
            cfg.threshold = int(index_threshold)
        store = Store(
            str(path),
            storage_options=storage_options,
            read_consistency_interval=read_consistency_interval,
            index=cfg,
        )
        if space is None:
            from tactus_memory.spaces import get_space

            recorded = store.get_meta("space")
            space = get_space(json.loads(recorded)["name"] if recorded else "minilm")
        return cls(store, space, background=background)

    def _load_registry(self) -> None:
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

    # ----------------------------------------------------------- senses
    @property
    def senses(self) -> dict[str, Sense]:
        """Live senses (can embed new items), name -> Sense."""
        return dict(self._live)

    def add_sense(self, sense: Sense) -> None:
        """Register a live sense. Raises SenseConflictError on a duplicate name or a space or
        dimension mismatch (also against a persisted registration of the same name)."""
        name = validate_sense_name(sense.name)
        with self._lock:
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
            self._stored[name] = StoredSense(name, sense.modality, sense.dim, provenance, centroid)
            self._live[name] = sense

    def _live_sense(self, name: str) -> Sense:
        validate_sense_name(name)
        if name in self._live:
            return self._live[name]
        if name in self._stored:
            raise self._stored[name]._not_loaded()
        raise UnknownSenseError(f"unknown sense {name!r}; registered: {sorted(self._stored)}")

    def _search_sense(self, name: str) -> Sense:
        validate_sense_name(name)
        if name in self._live:
            return self._live[name]
        if name in self._stored:
            return self._stored[name]
        raise UnknownSenseError(f"unknown sense {name!r}; registered: {sorted(self._stored)}")

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows, live or not, with row counts and calibration."""
        counts = self._sense_counts()
        out = []
        for name, s in sorted(self._stored.items()):
            c = self._calib.get(name)
            out.append(
                SenseInfo(
                    name=name,
                    modality=s.modality,
                    dim=s.dim,
                    provenance=s.provenance(),
                    live=name in self._live,
                    rows=counts.get(name, 0),
                    mu=c.mu if c else None,
                    sigma=c.sigma if c else None,
                )
            )
        return out

    # ----------------------------------------------------------- writes
    def add(
        self,
        session: str,
        sense: str,
        item: Any,
        *,
        t: float | None = None,
        t_end: float | None = None,
        meta: dict[str, Any] | None = None,
        id: str | None = None,  # noqa: A002  (the public contract names it id)
        source: str = "",
    ) -> str:
        """Remember one item; returns its id. ``t`` defaults to now (unix seconds), ``t_end``
        to ``t``. Passing ``id`` makes the call an idempotent upsert of that session's item of
        that sense; an id already used by another session or sense raises
        :class:`~tactus_memory.errors.IdConflictError` (nothing is written)."""
        return self.add_many(
            session,
            sense,
            [item],
            t=[t],
            t_end=[t_end],
            meta=[meta],
            ids=None if id is None else [id],
            source=source,
        )[0]

    def add_many(
        self,
        session: str,
        sense: str,
        items: Sequence[Any],
        *,
        t: Sequence[float | None] | float | None = None,
        t_end: Sequence[float | None] | float | None = None,
        meta: Sequence[dict[str, Any] | None] | dict[str, Any] | None = None,
        ids: Sequence[str] | None = None,
        source: str = "",
    ) -> list[str]:
        """Remember N items of one sense in one commit; returns their ids (in order).

        Everything is validated and embedded before the write: a failure writes nothing.
        """
        import pyarrow as pa

        session = validate_id(session, "session id")
        source = validate_source(source)
        s = self._live_sense(sense)
        items = list(items)
        n = len(items)
        if n == 0:
            return []
        if n > MAX_BATCH:
            raise InvalidInputError(f"{n} items in one call; limit {MAX_BATCH}")
        now = time.time()
        ts = [now if x is None else finite_float(x, "t") for x in _per_item(t, n, "t")]
        ends = [
            ts[i] if x is None else finite_float(x, "t_end")
            for i, x in enumerate(_per_item(t_end, n, "t_end"))
        ]
        for a, b in zip(ts, ends, strict=True):
            if b < a:
                raise InvalidInputError(f"t_end ({b}) is before t ({a})")
        metas = [_meta_json(m) for m in _per_item(meta, n, "meta")]
        upsert = ids is not None
        if upsert:
            if isinstance(ids, str) or len(ids) != n:
                raise InvalidInputError(f"ids must be a list of {n} ids")
            id_list = [validate_id(i, "item id") for i in ids]
            if len(set(id_list)) != n:
                raise InvalidInputError("ids contain duplicates")
        else:
            id_list = [uuid.uuid4().hex for _ in range(n)]
        canon = [s.validate(x) for x in items]
        vectors = as_unit_rows(s.embed(canon), self.space.dim, what=f"{sense} embedding")
        if vectors.shape[0] != n:
            raise InvalidInputError(f"sense {sense!r} returned {vectors.shape[0]} vectors for {n}")
        extras = [s.to_row(x) for x in canon]
        data = pa.table(
            {
                "id": id_list,
                "session": [session] * n,
                "sense": [s.name] * n,
                "t": ts,
                "t_end": ends,
                "vector": pa.FixedSizeListArray.from_arrays(
                    pa.array(vectors.reshape(-1), pa.float32()), self.space.dim
                ),
                "meta": metas,
                "text": [e.get("text") for e in extras],
                "raw": [e.get("raw") for e in extras],
                "source": [source] * n,
                "episode": pa.nulls(n, pa.int64()),
                "created": [now] * n,
            },
            schema=self.store.schema,
        )
        with self._lock:
            replaced: list[str] = []
            if upsert:  # under the commit lock: no racing writer can slip in between
                replaced = self.store.owned_ids(id_list, session, s.name)
            self.store.write(data, upsert=upsert)
            if self._counts is not None:
                counts = dict(self._counts)
                for name in replaced:  # an upsert may move an id to another sense
                    counts[name] -= 1
                counts[s.name] = counts.get(s.name, 0) + n
                self._counts = counts
        self._schedule_maintenance()
        return id_list

    def delete(self, ids: Sequence[str] | str) -> int:
        """Delete items by id; returns how many rows were removed."""
        if isinstance(ids, str):
            ids = [ids]
        where = Where().ids(list(ids)).sql()
        return self._delete(where)

    def delete_session(self, session: str) -> int:
        """Delete every item of a session; returns how many rows were removed."""
        return self._delete(Where().session(session).sql())

    def _delete(self, where: str | None) -> int:
        with self._lock:
            n = self.store.count(where)
            if n:
                self.store.delete(where)
                self._counts = None
            return n

    # ----------------------------------------------------------- maintenance
    def _schedule_maintenance(self) -> None:
        if not (self.store.needs_maintenance() or self._index_due()):
            return
        if not self.background:
            self.optimize()
            return
        if self._maint_thread is not None and self._maint_thread.is_alive():
            return
        self._maint_thread = threading.Thread(target=self._maintain_quietly, daemon=True)
        self._maint_thread.start()

    def _index_due(self) -> bool:
        return self.store.index_due(sum(self._sense_counts().values()))

    def _maintain_quietly(self) -> None:
        try:
            self.store.maintain()
        except Exception:  # noqa: BLE001  (a background thread must not die loudly; retried)
            log.exception("background maintenance failed; it will be retried")

    def optimize(self) -> None:
        """Build/retrain indexes if due and compact now (blocking)."""
        self.store.maintain(force=True)

    def wait_for_maintenance(self, timeout: float | None = None) -> None:
        if self._maint_thread is not None:
            self._maint_thread.join(timeout)

    # ----------------------------------------------------------- counts & calibration
    def _sense_counts(self) -> dict[str, int]:
        counts = self._counts
        if counts is None:
            import pyarrow.compute as pc

            col = self.store.scan(None, ["sense"]).column("sense")
            vc = pc.value_counts(col).to_pylist()
            counts = {d["values"]: int(d["counts"]) for d in vc}
            self._counts = counts
        return counts

    def _probe_vectors(self) -> np.ndarray:
        """(P, D) embedded probe bank, cached in the store per space."""
        if self._probes is None:
            key = f"probes:{self.space.name}:{len(PROBES)}"
            cached = self.store.get_meta(key)
            if cached is not None:
                arr = np.asarray(json.loads(cached), dtype=np.float32)
            else:
                arr = as_unit_rows(self.space.embed_texts(list(PROBES), query=True), self.space.dim)
                with self._lock:
                    _cache_write(self.store.set_meta, key, json.dumps(arr.round(6).tolist()))
            self._probes = as_unit_rows(arr, self.space.dim)
        return self._probes

    def calibration(self, sense: str) -> Calibration:
        """The null statistics of a sense, re-estimated when its row count has doubled."""
        rows = self._sense_counts().get(sense, 0)
        calib = self._calib.get(sense, Calibration())
        if not calib.stale(rows):
            return calib
        s = self._search_sense(sense)
        probes = s.query_transform(self._probe_vectors())
        sample = self.store.scan(Where().sense(sense).sql(), ["vector"], limit=SAMPLE)
        vecs = np.asarray(sample.column("vector").combine_chunks().flatten(), np.float32)
        vecs = vecs.reshape(-1, self.space.dim)
        calib = estimate(probes, vecs, rows)
        self._calib[sense] = calib
        with self._lock:
            row = next((r for r in self.store.sense_rows() if r["name"] == sense), None)
            if row is not None:
                row.update(mu=calib.mu, sigma=calib.sigma, calib_n=calib.n, updated=time.time())
                _cache_write(self.store.put_sense_row, row)
        return calib

    # ----------------------------------------------------------- search
    def search(
        self,
        query: str,
        k: int = 10,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        group: str | None = None,
        gap: float | None = None,
    ) -> list[Hit]:
        """Natural-language search over the chosen senses (default: every sense with rows).

        ``group="moment"`` returns Moments instead (see ``TemporalMixin.search_moments``)."""
        if group is not None:
            filters = {"senses": senses, "session": session, "after": after, "before": before}
            return self.search_grouped(query, k, group=group, gap=gap, source=source, **filters)
        query = _check_query_text(query)
        k = _check_k(k)
        base = self._filter(session=session, after=after, before=before, source=source)
        names = self._senses_to_search(senses)
        q = as_unit_rows(self.space.embed_texts([query], query=True), self.space.dim, what="query")
        return self._query(q, k, names, base, transform=True)

    def search_vector(
        self,
        vector: np.ndarray | Sequence[float],
        k: int = 10,
        *,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
        transform: bool = False,
    ) -> list[Hit]:
        """Search with a raw (D,) query vector. ``transform=True`` treats it as a text query
        embedding and applies each sense's query transform."""
        k = _check_k(k)
        q = as_unit_rows(vector, self.space.dim, what="query vector")
        if q.shape[0] != 1:
            raise InvalidInputError(f"one query vector expected, got {q.shape[0]}")
        base = self._filter(session=session, after=after, before=before, source=source)
        return self._query(q, k, self._senses_to_search(senses), base, transform=transform)

    def search_like(
        self,
        sense: str,
        example: Any = None,
        k: int = 10,
        *,
        vector: np.ndarray | Sequence[float] | None = None,
        senses: Sequence[str] | None = None,
        session: str | None = None,
        after: float | None = None,
        before: float | None = None,
        source: str | None = None,
    ) -> list[Hit]:
        """Query by example: embed ``example`` with ``sense`` (or take its precomputed
        ``vector``) and search that sense's rows (or ``senses``)."""
        validate_sense_name(sense)
        if vector is None:
            if example is None:
                raise InvalidInputError("search_like needs an example or vector=")
            s = self._live_sense(sense)
            q = as_unit_rows(s.embed([s.validate(example)]), self.space.dim, what="example")
        else:
            self._search_sense(sense)
            q = as_unit_rows(vector, self.space.dim, what="example vector")
        return self.search_vector(
            q[0],
            k,
            senses=senses or [sense],
            session=session,
            after=after,
            before=before,
            source=source,
        )

    def _filter(self, **kw: Any) -> Where:
        return (
            Where()
            .session(kw.get("session"))
            .overlaps(kw.get("after"), kw.get("before"))
            .source(kw.get("source"))
        )

    def _senses_to_search(self, senses: Sequence[str] | None) -> list[str]:
        if senses is None:
            counts = self._sense_counts()
            return [name for name in sorted(self._stored) if counts.get(name, 0) > 0]
        if isinstance(senses, str):
            senses = [senses]
        names = []
        for name in senses:
            self._search_sense(name)
            if name not in names:
                names.append(name)
        return names

    def _query(
        self,
        q: np.ndarray,
        k: int,
        senses: Sequence[str],
        base: Where,
        *,
        transform: bool,
        build: Callable[[dict[str, Any], float, float], Hit] | None = None,
    ) -> list[Hit]:
        """The one search path: q (1, D) unit query -> per-sense query transform, prefiltered
        ANN (or exact flat) search, calibrated scores, merged top k. ``base`` holds the
        non-sense conditions (session, time, source, ...); temporal operators reuse this.

        Senses whose transformed query vectors coincide (e.g. identity transforms) share one
        LanceDB query fetching ``k * len(group)`` candidates; a sense with fewer than k of
        them gets its own query unless its best possible missing z-score (bounded by the
        lowest candidate cosine) cannot reach the current k-th score. The merge is therefore
        the same as one query per sense, at a fraction of the cost.
        """
        counts = self._sense_counts()
        active = [name for name in senses if counts.get(name, 0) > 0]
        groups: list[tuple[np.ndarray, list[str]]] = []
        for name in active:
            qs = q
            if transform:
                s = self._search_sense(name)
                qs = as_unit_rows(s.query_transform(q), self.space.dim, what="query")
            for vec, names in groups:
                if np.array_equal(vec, qs):
                    names.append(name)
                    break
            else:
                groups.append((qs, [name]))
        calib = {name: self.calibration(name) for name in active}
        scored: list[tuple[float, float, dict[str, Any]]] = []
        for vec, names in groups:
            scored.extend(self._search_group(vec[0], k, names, base, counts, calib, scored))
        scored.sort(key=lambda x: -x[0])
        make = build or _hit
        return [make(row, score, cos) for score, cos, row in scored[:k]]

    def _search_group(
        self,
        vec: np.ndarray,
        k: int,
        names: list[str],
        base: Where,
        counts: dict[str, int],
        calib: dict[str, Calibration],
        found: list[tuple[float, float, dict[str, Any]]],
    ) -> list[tuple[float, float, dict[str, Any]]]:
        """One ANN query for senses sharing a query vector (D,), plus follow-ups if needed."""
        total = sum(counts.values())
        every = {name for name, c in counts.items() if c > 0}
        where = Where(list(base.parts))
        if set(names) != every:
            where.senses(names)
        sql = where.sql()
        allowed = self.store.count(sql) if base.parts else sum(counts[n] for n in names)
        if allowed == 0:
            return []
        want = k * len(names)
        rows = self.store.vector_search(vec, want, sql, allowed=allowed, total=total)
        out = [self._scored(row, calib) for row in rows.to_pylist()]
        if len(names) == 1 or len(out) < want:
            return out  # complete: every allowed row was a candidate or one sense only
        floor = min(cos for _, cos, _ in out)
        have = {name: sum(1 for _, _, r in out if r["sense"] == name) for name in names}
        for name in names:
            if have[name] >= k:
                continue
            ranked = sorted([z for z, _, _ in found] + [z for z, _, _ in out], reverse=True)
            kth = ranked[k - 1] if len(ranked) >= k else -math.inf
            if calib[name].score(floor) <= kth:
                continue  # nothing of this sense below the floor can enter the top k
            one = Where(list(base.parts)).sense(name).sql()
            n_one = self.store.count(one) if base.parts else counts[name]
            extra = self.store.vector_search(vec, k, one, allowed=n_one, total=total)
            out = [x for x in out if x[2]["sense"] != name]
            out.extend(self._scored(row, calib) for row in extra.to_pylist())
        return out

    @staticmethod
    def _scored(
        row: dict[str, Any], calib: dict[str, Calibration]
    ) -> tuple[float, float, dict[str, Any]]:
        cos = 1.0 - float(row.pop("_distance"))
        return float(calib[row["sense"]].score(cos)), cos, row

    # ----------------------------------------------------------- reads
    def get_item(self, id: str, *, vector: bool = False) -> Item:  # noqa: A002
        """One stored item with ``raw`` decoded (by its sense when live, else as npy/text)."""
        cols = [*HIT_COLUMNS, "raw", "created"] + (["vector"] if vector else [])
        rows = self.store.scan(Where().ids([id]).sql(), cols, limit=1).to_pylist()
        if not rows:
            raise NotFoundError(f"no item with id {id!r}")
        row = rows[0]
        s = self._live.get(row["sense"])
        if s is not None:
            raw = s.from_row(row)
        else:
            raw = bytes_to_array(row["raw"]) if row.get("raw") is not None else row.get("text")
        return Item(
            id=row["id"],
            session=row["session"],
            sense=row["sense"],
            t=row["t"],
            t_end=row["t_end"],
            meta=json.loads(row["meta"] or "{}"),
            text=row.get("text"),
            raw=raw,
            source=row.get("source") or "",
            episode=row.get("episode"),
            created=row["created"],
            vector=row.get("vector"),
        )

    def sessions(self) -> list[SessionSummary]:
        """A summary per session (counts per sense, time span), sorted by id."""
        return self._summaries(None)

    def session(self, session: str) -> SessionSummary:
        out = self._summaries(Where().session(session).sql())
        if not out:
            raise NotFoundError(f"no session {session!r}")
        return out[0]

    def _summaries(self, where: str | None) -> list[SessionSummary]:
        tbl = self.store.scan(where, ["session", "sense", "t", "t_end"])
        if tbl.num_rows == 0:
            return []
        agg = tbl.group_by(["session", "sense"]).aggregate(
            [("t", "min"), ("t_end", "max"), ("t", "count")]
        )
        by: dict[str, dict[str, Any]] = {}
        for r in agg.to_pylist():
            d = by.setdefault(r["session"], {"counts": {}, "t_min": math.inf, "t_max": -math.inf})
            d["counts"][r["sense"]] = int(r["t_count"])
            d["t_min"] = min(d["t_min"], r["t_min"])
            d["t_max"] = max(d["t_max"], r["t_end_max"])
        return [
            SessionSummary(
                id=sid,
                n=sum(d["counts"].values()),
                counts=dict(sorted(d["counts"].items())),
                t_min=d["t_min"],
                t_max=d["t_max"],
            )
            for sid, d in sorted(by.items())
        ]

    def close(self) -> None:
        """Let background maintenance finish (the store needs no other closing)."""
        self.wait_for_maintenance()

    def __enter__(self) -> Memory:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return self.store.count()

    def __repr__(self) -> str:
        return f"Memory({self.store.uri!r}, space={self.space.name!r}, senses={sorted(self._live)})"


def _hit(row: dict[str, Any], score: float, cos: float) -> Hit:
    return Hit(
        id=row["id"],
        session=row["session"],
        sense=row["sense"],
        t=row["t"],
        t_end=row["t_end"],
        score=score,
        cosine=cos,
        meta=json.loads(row["meta"] or "{}"),
        text=row.get("text"),
        source=row.get("source") or "",
        episode=row.get("episode"),
    )
