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

Where the parts live: result models in :mod:`tactus_memory.models`, the sense registry
(live/stored senses, counts, calibration) in :mod:`tactus_memory.registry`, the ranked search
in :mod:`tactus_memory.ranking`, query checks and the :class:`~tactus_memory.query.Scope` in
:mod:`tactus_memory.query`, the temporal operators in :mod:`tactus_memory.temporal`.

Extension points (temporal operators and the service build on these, not on LanceDB):
``Where`` (validated filter builder: session/senses/ids/source/episode/overlaps/t_range),
``Memory.rank(q, k, senses, where, transform=..., build=...)`` (the one ranked search
path), ``Memory.store.scan(where, columns, limit)`` (unranked reads), ``Memory.calibration``.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from datetime import timedelta
from typing import Any

import numpy as np
from typing_extensions import Unpack

from tactus_memory.episodes import EPISODE_MAX_GAP, EPISODE_MEAN_COS, EPISODE_MIN_COS, Episode
from tactus_memory.errors import InvalidInputError, NotFoundError
from tactus_memory.limits import MAX_BATCH, MAX_K, MAX_META_BYTES
from tactus_memory.matching import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    MatchKwargs,
    split_match,
)
from tactus_memory.models import (
    ClockOffset,
    Context,
    Evidence,
    Hit,
    Item,
    Moment,
    Occurrences,
    SenseInfo,
    SessionSummary,
    TimelineItem,
)
from tactus_memory.query import Scope, ScopeKwargs, check_k, check_query_text, embed_query
from tactus_memory.ranking import Ranker
from tactus_memory.registry import SenseRegistry, StoredSense
from tactus_memory.scoring import Calibration
from tactus_memory.senses import Sense, TextSense, bytes_to_array, validate_sense_name
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
from tactus_memory.temporal import Temporal
from tactus_memory.vectors import as_unit_rows

log = logging.getLogger(__name__)

#: re-exported: `from tactus_memory.memory import Hit, Item, MAX_K, ...` keeps working
__all__ = [
    "MAX_BATCH",
    "MAX_K",
    "MAX_META_BYTES",
    "Hit",
    "Item",
    "Memory",
    "Scope",
    "SenseInfo",
    "SessionSummary",
    "StoredSense",
]
_check_k = check_k  # old private names, still imported by other branches
_check_query_text = check_query_text


# --------------------------------------------------------------------------- helpers
def _meta_json(meta: Any) -> str:
    if meta is None:
        return "{}"
    if not isinstance(meta, dict) or not all(isinstance(key, str) for key in meta):
        raise InvalidInputError("meta must be a dict with string keys")
    try:
        out = json.dumps(meta, allow_nan=False, sort_keys=True, ensure_ascii=False)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"meta is not JSON-serialisable: {exc}") from None
    if len(out.encode()) > MAX_META_BYTES:
        raise InvalidInputError(f"meta is larger than {MAX_META_BYTES} bytes as JSON")
    return out


def _per_item(value: Any, n: int, what: str) -> list[Any]:
    """A list of n values, or a scalar/None broadcast to n."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise InvalidInputError(f"{what} has {len(value)} entries for {n} items")
        return list(value)
    return [value] * n


def _options_for(sense: Sense, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options ``sense.validate`` takes (its ``validate_options``): an option a sense
    does not declare does not apply to it (``calibrated`` means nothing to a text sense)."""
    return {k: v for k, v in (options or {}).items() if k in sense.validate_options}


# --------------------------------------------------------------------------- memory
class Memory:
    """A robot memory: items of every sense in one LanceDB table, one embedding space.

    Use :meth:`open`. Thread-safe: writes are serialised by a lock, reads run concurrently.
    """

    def __init__(self, store: Store, space: Space, *, background: bool = True) -> None:
        self.store = store
        self.space = space
        self.background = background
        self.lock = threading.RLock()
        self._maint_thread: threading.Thread | None = None
        store.bind_space(space.name, int(space.dim))
        self.registry = SenseRegistry(store, space, self.lock)
        self.ranker = Ranker(store, self.registry)
        self.temporal = Temporal(self)
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

    # ----------------------------------------------------------- senses (registry.py)
    @property
    def senses(self) -> dict[str, Sense]:
        """Live senses (can embed new items), name -> Sense."""
        return self.registry.senses

    def add_sense(self, sense: Sense) -> None:
        """Register a live sense. Raises SenseConflictError on a duplicate name or a space or
        dimension mismatch (also against a persisted registration of the same name)."""
        self.registry.add_sense(sense)

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows, live or not, with row counts and calibration."""
        return self.registry.sense_info()

    def calibration(self, sense: str) -> Calibration:
        """The null statistics of a sense, re-estimated when its row count has doubled."""
        return self.registry.calibration(sense)

    def resolve_senses(self, senses: Sequence[str] | None) -> list[str]:
        """The senses a search covers: the named ones (checked), or every sense with rows."""
        return self.registry.resolve(senses)

    def _sense_counts(self) -> dict[str, int]:
        return self.registry.counts()

    def _probe_vectors(self) -> np.ndarray:
        return self.registry.probe_vectors()

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
        options: Mapping[str, Any] | None = None,
    ) -> str:
        """Remember one item; returns its id. ``t`` defaults to now (unix seconds), ``t_end``
        to ``t``. Passing ``id`` makes the call an idempotent upsert."""
        return self.add_many(
            session,
            sense,
            [item],
            t=[t],
            t_end=[t_end],
            meta=[meta],
            ids=None if id is None else [id],
            source=source,
            options=options,
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
        options: Mapping[str, Any] | None = None,
    ) -> list[str]:
        """Remember N items of one sense in one commit; returns their ids (in order).

        Everything is validated and embedded before the write: a failure writes nothing.
        ``options`` go to the sense's ``validate`` (e.g. ``{"calibrated": True}`` for touch);
        the sense's ``embed`` then takes the validated items as they are.
        """
        import pyarrow as pa

        session = validate_id(session, "session id")
        source = validate_source(source)
        s = self.registry.live_sense(sense)
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
        opts = _options_for(s, options)
        canon = [s.validate(x, **opts) for x in items]
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
        with self.lock:
            replaced: list[str] = []
            if upsert and self.registry.counting:
                where = Where().ids(id_list).sql()
                replaced = self.store.scan(where, ["sense"]).column("sense").to_pylist()
            self.store.write(data, upsert=upsert)
            self.registry.note_write(s.name, n, replaced)
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
        with self.lock:
            n = self.store.count(where)
            if n:
                self.store.delete(where)
                self.registry.forget_counts()
            return n

    def validate_item(self, sense: str, item: Any, options: Mapping[str, Any] | None = None) -> Any:
        """``item`` checked (and canonicalised) by the live ``sense``, as ``add`` would store
        it; ``add``/``add_many`` take the result as it is (a stream validates each window
        before queueing its write)."""
        s = self.registry.live_sense(sense)
        return s.validate(item, **_options_for(s, options))

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
        return self.store.index_due(sum(self.registry.counts().values()))

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

    # ----------------------------------------------------------- search
    def search(
        self,
        query: str,
        k: int = 10,
        *,
        group: str | None = None,
        gap: float | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit] | list[Moment]:
        """Natural-language search over the scope's senses (default: every sense with rows).

        Filters: ``session``, ``senses``, ``source``, ``after``/``before`` (or one ``scope=``
        :class:`Scope`). ``group="moment"`` returns Moments instead (see
        :meth:`search_moments`); the query is embedded once either way."""
        where = Scope.of(**scope)
        if group is not None and group != "moment":
            raise InvalidInputError(f"unknown group {group!r}; use group='moment'")
        if group is not None:
            q = embed_query(self.space, query)
            gap = DEFAULT_MOMENT_GAP if gap is None else gap
            return self.temporal.moments(q, k, where, split_match({})[1], gap)
        query = check_query_text(query)
        k = check_k(k)
        base = where.where()
        names = self.resolve_senses(where.senses)
        return self.rank(embed_query(self.space, query), k, names, base, transform=True)

    def search_vector(
        self,
        vector: np.ndarray | Sequence[float],
        k: int = 10,
        *,
        transform: bool = False,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit]:
        """Search with a raw (D,) query vector. ``transform=True`` treats it as a text query
        embedding and applies each sense's query transform."""
        k = check_k(k)
        q = as_unit_rows(vector, self.space.dim, what="query vector")
        if q.shape[0] != 1:
            raise InvalidInputError(f"one query vector expected, got {q.shape[0]}")
        where = Scope.of(**scope)
        base = where.where()
        return self.rank(q, k, self.resolve_senses(where.senses), base, transform=transform)

    def search_like(
        self,
        sense: str,
        example: Any = None,
        k: int = 10,
        *,
        vector: np.ndarray | Sequence[float] | None = None,
        options: Mapping[str, Any] | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit]:
        """Query by example: embed ``example`` with ``sense`` (validated with ``options``) or
        take its precomputed ``vector``, and search that sense's rows (or ``senses``)."""
        validate_sense_name(sense)
        if vector is None:
            if example is None:
                raise InvalidInputError("search_like needs an example or vector=")
            s = self.registry.live_sense(sense)
            item = s.validate(example, **_options_for(s, options))
            q = as_unit_rows(s.embed([item]), self.space.dim, what="example")
        else:
            self.registry.search_sense(sense)
            q = as_unit_rows(vector, self.space.dim, what="example vector")
        where = Scope.of(**scope)
        if not where.senses:
            where = Scope.of(where, senses=[sense])
        return self.search_vector(q[0], k, scope=where)

    def rank(
        self,
        q: np.ndarray,
        k: int,
        senses: Sequence[str],
        base: Where,
        *,
        transform: bool,
        build: Callable[[dict[str, Any], float, float], Hit] | None = None,
    ) -> list[Hit]:
        """The one ranked search path (see :mod:`tactus_memory.ranking`): (1, D) unit query
        ``q``, the senses searched, ``base`` the non-sense conditions."""
        return self.ranker.rank(q, k, senses, base, transform=transform, build=build)

    _query = rank  # the old private name

    # ----------------------------------------------------------- temporal (temporal.py)
    def matches(self, query: str, **kw: Unpack[MatchKwargs]) -> list[Evidence]:
        """Every item matching ``query`` (see :mod:`tactus_memory.matching`), in aligned time
        order. Keywords: the scope (session, senses, source, after, before, or ``scope=``)
        and the match bar (``threshold``, ``relative``)."""
        return self.temporal.matches(query, *split_match(kw))

    def occurrences(
        self,
        query: str,
        *,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
        **kw: Unpack[MatchKwargs],
    ) -> Occurrences:
        """Distinct occurrences of ``query`` (see :meth:`Temporal.occurrences`)."""
        scope, match = split_match(kw)
        return self.temporal.occurrences(query, scope, match, merge_gap, per_stream)

    def count(
        self,
        query: str,
        *,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
        **kw: Unpack[MatchKwargs],
    ) -> int:
        """How many distinct times ``query`` happened (see :meth:`occurrences`)."""
        return self.occurrences(query, merge_gap=merge_gap, per_stream=per_stream, **kw).count

    def last(
        self, query: str, *, merge_gap: float = DEFAULT_MERGE_GAP, **kw: Unpack[MatchKwargs]
    ) -> Moment | None:
        """The most recent occurrence of ``query`` (latest aligned start), or None."""
        moments = self.occurrences(query, merge_gap=merge_gap, **kw).moments
        return moments[-1] if moments else None

    def first(
        self, query: str, *, merge_gap: float = DEFAULT_MERGE_GAP, **kw: Unpack[MatchKwargs]
    ) -> Moment | None:
        """The earliest occurrence of ``query`` (earliest aligned start), or None."""
        moments = self.occurrences(query, merge_gap=merge_gap, **kw).moments
        return moments[0] if moments else None

    def before(
        self,
        anchor: str,
        window: float = DEFAULT_WINDOW,
        *,
        anchor_senses: Sequence[str] | None = None,
        **kw: Unpack[MatchKwargs],
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor`` (see
        :meth:`Temporal.around`)."""
        scope, match = split_match(kw)
        return self.temporal.around("before", anchor, window, scope, match, anchor_senses)

    def after(
        self,
        anchor: str,
        window: float = DEFAULT_WINDOW,
        *,
        anchor_senses: Sequence[str] | None = None,
        **kw: Unpack[MatchKwargs],
    ) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor`` (see
        :meth:`Temporal.around`)."""
        scope, match = split_match(kw)
        return self.temporal.around("after", anchor, window, scope, match, anchor_senses)

    def search_moments(
        self,
        query: str,
        k: int = 10,
        *,
        gap: float = DEFAULT_MOMENT_GAP,
        **kw: Unpack[MatchKwargs],
    ) -> list[Moment]:
        """Search grouped into moments (see :meth:`Temporal.moments`)."""
        scope, match = split_match(kw)
        return self.temporal.moments(embed_query(self.space, query), k, scope, match, gap)

    def timeline(
        self,
        session: str,
        senses: Sequence[str] | None = None,
        after: float | None = None,
        before: float | None = None,
        episodes: bool = False,
        *,
        source: str | None = None,
        limit: int | None = None,
    ) -> list[TimelineItem] | list[Episode]:
        """The session's items (or, with ``episodes=True``, its episodes) in aligned time
        order; ``after``/``before`` use overlap semantics on the aligned clock. Raises
        NotFoundError for an unknown session."""
        session = validate_id(session, "session id")
        scope = Scope(session=session, senses=senses, source=source, after=after, before=before)
        return self.temporal.timeline(scope, episodes, limit)

    def segment_episodes(
        self,
        session: str | None = None,
        *,
        min_cos: float = EPISODE_MIN_COS,
        mean_cos: float = EPISODE_MEAN_COS,
        max_gap: float = EPISODE_MAX_GAP,
    ) -> int:
        """Segment streams into stored episodes (see :meth:`Temporal.segment_episodes`)."""
        return self.temporal.segment_episodes(
            session, min_cos=min_cos, mean_cos=mean_cos, max_gap=max_gap
        )

    def episodes(
        self, session: str, *, senses: Sequence[str] | None = None, source: str | None = None
    ) -> list[Episode]:
        """The session's episodes in aligned time order (segmenting it first if needed)."""
        return self.temporal.episodes(session, senses=senses, source=source)

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock."""
        self.temporal.set_clock_offset(session, sense, offset, source)

    def clock_offsets(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        return self.temporal.clock_offsets(session)

    # ----------------------------------------------------------- reads
    def get_item(self, id: str, *, vector: bool = False) -> Item:  # noqa: A002
        """One stored item with ``raw`` decoded (by its sense when live, else as npy/text)."""
        cols = [*HIT_COLUMNS, "raw", "created"] + (["vector"] if vector else [])
        rows = self.store.scan(Where().ids([id]).sql(), cols, limit=1).to_pylist()
        if not rows:
            raise NotFoundError(f"no item with id {id!r}")
        row = rows[0]
        s = self.registry.senses.get(row["sense"])
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
        return (
            f"Memory({self.store.uri!r}, space={self.space.name!r}, senses={sorted(self.senses)})"
        )

    def session_ids(self) -> list[str]:
        """Every session id, sorted."""
        return [s.id for s in self.sessions()]
