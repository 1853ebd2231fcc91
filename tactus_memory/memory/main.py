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

Search: the query is embedded once, passes each sense's query transform, a prefiltered ANN
search per sense, cosines calibrated into z-scores (:mod:`tactus_memory.search.scoring`) so
senses merge fairly; touch answers are grasps by default. Time filters use overlap: an item
spanning ``[t, t_end]`` matches when ``t_end >= after`` and ``t <= before``.

Senses: "text" is registered on open. Other live senses are rebuilt after a reopen by
``memory.restore_senses()`` (from the record each registered sense leaves in the store) or
re-added with ``add_sense``; their registration (name, modality, dim, provenance, optional
``query_centroid``, score calibration) is persisted, so a sense with rows can be *searched*
without its live object: its query transform is rebuilt from the stored centroid
(``q - c``, renormalised).

Where the parts live: results in :mod:`tactus_memory.results`, the sense registry in
:mod:`tactus_memory.senses.stored`, the ranked search in :mod:`tactus_memory.search.ranking`,
``Scope`` in :mod:`tactus_memory.query`, ``memory.count``/``last``/... (the methods of
``memory.temporal``, named in the class body) in :mod:`tactus_memory.temporal.operators`,
the places (``memory.where``/``at``/...) in :mod:`tactus_memory.memory.places`.

Extension points (temporal operators and the service build on these, not on LanceDB):
``Where`` (validated filter builder: session/senses/ids/source/episode/overlaps/t_range),
``Memory.rank(q, k, senses, where, transform=...)`` (the one ranked search
path), ``Memory.store.scan(where, columns, limit)`` (unranked reads), ``Memory.calibration``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Collection, Mapping, Sequence
from contextlib import AbstractContextManager
from datetime import timedelta
from typing import Any

import numpy as np
from typing_extensions import Unpack

from tactus_memory.adapters.text import TextSense
from tactus_memory.batches import AddKwargs, WriteKwargs, one_item
from tactus_memory.contract import MemoryAPI
from tactus_memory.errors import InvalidInputError, NotFoundError
from tactus_memory.identity import DEFAULT_TENANT
from tactus_memory.matching import DEFAULT_MOMENT_GAP, mark_matches
from tactus_memory.memory.parts import Part
from tactus_memory.memory.places import Places
from tactus_memory.memory.writes import WritePath
from tactus_memory.names import validate_sense_name
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.query import Scope, ScopeKwargs, check_k, embed_query
from tactus_memory.results import (
    Grasp,
    Hit,
    Item,
    Moment,
    SenseInfo,
    SessionSummary,
    Stored,
    item_from_row,
)
from tactus_memory.search.grasps import DEFAULT_GROUP, check_group
from tactus_memory.search.ordering import candidates, sort_hits
from tactus_memory.search.ranking import Ranker
from tactus_memory.search.scoring import Calibration
from tactus_memory.search.teaching import Teachings
from tactus_memory.senses.base import Sense, bytes_to_array
from tactus_memory.senses.stored import SenseRegistry
from tactus_memory.settings import DEFAULT_MEMORY, Settings
from tactus_memory.spaces.base import Space
from tactus_memory.storage.retention import drop_orphaned_teachings
from tactus_memory.storage.rows import options_for, summarise
from tactus_memory.storage.scheduler import Background
from tactus_memory.storage.store import Store
from tactus_memory.storage.tables import HIT_COLUMNS, IndexConfig
from tactus_memory.storage.tenants import tenant_uri
from tactus_memory.temporal.operators import Temporal
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import DEFAULT_FRAME, Where

log = logging.getLogger(__name__)


class Memory(AbstractContextManager["Memory"]):
    """A robot memory: items of every sense in one LanceDB table, one embedding space.

    Use :meth:`open`. Thread-safe: writes are serialised by a lock, reads run concurrently.
    """

    def __init__(
        self, store: Store, space: Space, *, background: bool = True, tenant: str = DEFAULT_TENANT
    ) -> None:
        self.store = store
        #: whose memory this is (``Memory.open(path, tenant=...)``; the store's root: default)
        self.tenant = tenant
        self.space = space
        self.background = background
        self.lock = threading.RLock()
        store.bind_space(space.name, int(space.dim), space.fingerprint())
        self.registry = SenseRegistry(store, space, self.lock)
        # live rows for the index threshold: the table's own count, as Store.maintain uses
        self._maintenance = Background(store, store.count, background=background)
        store.on_commit = self._schedule_maintenance  # every table, not only items
        self.ranker = Ranker(store, self.registry)
        self.temporal = Temporal(store, self.registry, self.ranker, space, self.lock)
        self.places = Places(store, self.lock, self.registry, space, self.temporal)
        self.write_path = WritePath(store, self.registry, space, self.lock, self.places)
        #: objects taught by example (:mod:`tactus_memory.search.teaching`)
        self.teachings = Teachings(store, self.registry, space, self.lock)
        self.ranker.steer = self.teachings.steer
        self.add_sense(TextSense(space))

    # ----------------------------------------------------------- the parts' methods
    # ``memory.count(q, ...)`` IS ``memory.temporal.count``: one implementation and one
    # docstring, the part's (:class:`~tactus_memory.memory.parts.Part`); the temporal questions
    matches = Part("temporal", Temporal.matches)
    occurrences = Part("temporal", Temporal.occurrences)
    count = Part("temporal", Temporal.count)
    last = Part("temporal", Temporal.last)
    first = Part("temporal", Temporal.first)
    before = Part("temporal", Temporal.before)
    after = Part("temporal", Temporal.after)
    search_moments = Part("temporal", Temporal.search_moments)
    timeline = Part("temporal", Temporal.timeline)
    segment_episodes = Part("temporal", Temporal.segment_episodes)
    episodes = Part("temporal", Temporal.episodes)
    set_clock_offset = Part("temporal", Temporal.set_clock_offset)
    clock_offsets = Part("temporal", Temporal.clock_offsets)
    # the write calls (:mod:`tactus_memory.memory.writes`)
    prepare_write = Part("write_path", WritePath.prepare_write)
    commit_writes = Part("write_path", WritePath.commit_writes)
    validate_item = Part("write_path", WritePath.validate_item)
    # the place questions (:mod:`tactus_memory.memory.places`)
    add_poses = Part("places", Places.add_poses)
    place_items = Part("places", Places.place_items)
    trajectory = Part("places", Places.trajectory)
    where = Part("places", Places.where)
    at = Part("places", Places.at)
    # objects taught by example (:mod:`tactus_memory.search.teaching`)
    teach = Part("teachings", Teachings.teach)
    taught = Part("teachings", Teachings.taught)
    forget = Part("teachings", Teachings.forget)

    # ----------------------------------------------------------- construction
    @classmethod
    def open(
        cls,
        path: str = DEFAULT_MEMORY,
        space: Space | str | None = None,
        *,
        space_path: str | None = None,
        space_dim: int | None = None,
        storage_options: dict[str, str] | None = None,
        index: IndexConfig | None = None,
        index_threshold: int | None = None,
        read_consistency_interval: timedelta | float | str | None = "env",
        background: bool = True,
        maintenance: MaintenanceConfig | None = None,
        tenant: str = DEFAULT_TENANT,
    ) -> Memory:
        """Open (or create) a memory at ``path``: a local directory, ``file://``, or an
        object-storage URI (``s3://``, ``gs://``, ``az://``) with ``storage_options``.

        ``space`` defaults to the space the store records (MiniLM, ``get_space("minilm")``, for
        a new store); a store created with another space raises
        :class:`~tactus_memory.errors.SpaceMismatchError` naming both. A space name (``str``),
        ``space_path`` and ``space_dim`` (else ``TACTUS_SPACE*`` from the environment) go
        through :func:`~tactus_memory.spaces.resolve.resolve_space`: a Qwen3-VL store reopens
        with ``space_path=DIR``, and a missing or other model folder raises a one-line
        :class:`~tactus_memory.errors.SpaceConfigError`.

        Several processes may open one store: each sees the others' commits within
        ``read_consistency_interval`` (default ``TACTUS_READ_CONSISTENCY`` or 1 s), and only
        the one whose ``maintenance.maintain`` is true compacts and cleans up
        (:mod:`tactus_memory.storage.compaction`, :mod:`tactus_memory.storage.connect`).

        ``tenant``: whose memory in the store this is (:mod:`tactus_memory.storage.tenants`):
        every read and write of the returned memory sees that tenant's sessions and ids only.
        """
        cfg = index or IndexConfig()
        if index_threshold is not None:
            cfg.threshold = int(index_threshold)
        if (isinstance(read_consistency_interval, str) and read_consistency_interval == "env") or (
            maintenance is None
        ):
            settings = Settings()  # read once, here: storage reads no settings
            if isinstance(read_consistency_interval, str):
                read_consistency_interval = settings.read_consistency
            maintenance = maintenance or settings.maintenance()
        assert not isinstance(read_consistency_interval, str)  # "env" read above
        store = Store(
            tenant_uri(str(path), tenant),
            storage_options=storage_options,
            read_consistency_interval=read_consistency_interval,
            index=cfg,
            maintenance=maintenance,
            tenant=tenant,
        )
        if not isinstance(space, Space):
            from tactus_memory.spaces.resolve import SpaceChoice, recorded_space, resolve_space

            choice = SpaceChoice(space, None if space_path is None else str(space_path), space_dim)
            space = resolve_space(choice, recorded_space(store.get_meta("space")))
        return cls(store, space, background=background, tenant=tenant)

    # ----------------------------------------------------------- senses (senses/stored.py)
    @property
    def senses(self) -> dict[str, Sense]:
        """Live senses (can embed new items), name -> Sense."""
        return self.registry.senses

    def add_sense(self, sense: Sense) -> None:
        """Register a live sense. Raises SenseConflictError on a duplicate name or a space or
        dimension mismatch (also against a persisted registration of the same name)."""
        self.registry.add_sense(sense)

    def restore_senses(self, skip: Collection[str] = ()) -> dict[str, str]:
        """Rebuild the live senses this store records (all but ``skip``) from their records
        (:mod:`tactus_memory.senses.plugins`); returns why each that could not be was not."""
        return self.registry.restore(skip)

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows, live or not, with row counts and calibration, and
        what each recognises: its trained ``classes`` and the labels ``taught`` to it."""
        out = []
        for info in self.registry.sense_info():
            classes = self.teachings.targets(info.name, taught=False)[0]
            taught = self.teachings.labels(info.name)
            out.append(info.model_copy(update={"classes": classes, "taught": taught}))
        return out

    def calibration(self, sense: str) -> Calibration:
        """The null statistics of a sense, re-estimated when its row count has doubled."""
        return self.registry.calibration(sense)

    def resolve_senses(self, senses: Sequence[str] | None) -> list[str]:
        """The senses a search covers: the named ones (checked), or every sense with rows."""
        return self.registry.resolve(senses)

    # ----------------------------------------------------------- writes
    def add(
        self,
        session: str,
        sense: str,
        item: Any,
        *,
        position: Sequence[float] | None = None,
        frame: str = DEFAULT_FRAME,
        **kw: Unpack[AddKwargs],
    ) -> str:
        """Remember one item; returns its id. The keywords (:class:`AddKwargs`): ``t``
        defaults to now (unix seconds), ``t_end`` to ``t``; ``meta``; ``source``; ``options``
        for the sense. Passing ``id`` makes the call an idempotent upsert of that session's
        item of that sense; an id already used by another session or sense raises
        :class:`~tactus_memory.errors.IdConflictError` (nothing is written). ``position``
        ``(x, y, z)`` in ``frame`` says where it happened (default: from the session's
        poses, :mod:`tactus_memory.memory.places`)."""
        batch: dict[str, Any] = dict(one_item(kw))
        return self.add_many(
            session,
            sense,
            [item],
            **batch,
            position=None if position is None else [position],
            frame=frame,
            skip_idle=False,  # one window: an idle one is refused (IdleWindowError)
        )[0]

    def add_many(
        self, session: str, sense: str, items: Sequence[Any], **kw: Unpack[WriteKwargs]
    ) -> Stored:
        """Remember N items of one sense in one commit; returns their ids (in order), a
        list whose ``skipped`` names the items skipped rather than stored: ``(index,
        "idle")`` for a touch window with no contact (an idle hand is never stored as a
        grasp; the other windows are). ``skip_idle=False`` raises ``IdleWindowError``.

        Everything else is validated and embedded before the write: a failure writes nothing.
        ``options`` go to the sense's ``validate`` (e.g. ``{"calibrated": True}`` for touch);
        the sense's ``embed`` then takes the validated items as they are. The keywords are
        :meth:`prepare_write`'s.
        """
        write = self.prepare_write(session, sense, items, **kw)
        return self.commit_writes([write])[0]

    def delete(self, ids: Sequence[str] | str) -> int:
        """Delete items by id; returns how many rows were removed."""
        if isinstance(ids, str):
            ids = [ids]
        where = Where().ids(list(ids)).sql()
        deleted = self._delete(where)
        if deleted:  # a teaching whose windows are all gone goes with them
            with self.lock:
                drop_orphaned_teachings(self.store)
        return deleted

    def read_latest(self) -> None:
        """Every table of the store at its latest version now, whoever committed it (another
        process of ``tactus serve --workers N``): the next read sees every write acknowledged
        before it (read-your-writes); the caches keyed by table versions follow."""
        self.store.read_latest()
        self.places.poses.read_latest()

    def delete_session(self, session: str) -> int:
        """Delete every item of a session, its poses, clock offsets and teachings; returns the
        item rows removed."""
        deleted = self._delete(Where().session(session).sql())
        self.teachings.drop_session(session)
        self.places.delete_session(session)
        self.temporal.clocks.drop_session(session)  # its one meta row
        return deleted

    def _delete(self, where: str | None) -> int:
        with self.lock:
            self.store.integrity.require()  # before counting: a damaged store may not count
            n = self.store.count(where)
            if n and where is not None:  # None (every row): never asked by delete()
                self.store.delete(where)
                self.registry.forget_counts()
            return n

    # ----------------------------------------------------------- maintenance
    def _schedule_maintenance(self) -> None:
        """After every commit of any table (``Store.on_commit``). Never raises: the commit
        is stored; maintenance is scheduled again after the next one."""
        try:
            self._maintenance.schedule()
        except Exception:  # noqa: BLE001
            log.exception("scheduling maintenance after a commit failed")

    def maintain_if_due(self) -> None:
        """Start a background maintenance pass when one is due without a new commit
        (retention, or deleted rows to erase from the files); ``tactus serve`` calls it every
        ``maintain_interval`` seconds, so an idle server still expires and erases."""
        self._schedule_maintenance()

    def optimize(self) -> None:
        """Build/retrain indexes if due and compact now (blocking)."""
        self.store.maintain(force=True)

    def wait_for_maintenance(self, timeout: float | None = None) -> None:
        self._maintenance.wait(timeout)

    # ----------------------------------------------------------- search
    def search(
        self,
        query: str,
        k: int = 10,
        *,
        group: str | None = DEFAULT_GROUP,
        gap: float | None = None,
        pool: str = "mean",
        sort: str | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit] | list[Moment] | list[Grasp]:
        """Natural-language search over the scope's senses (default: every sense with rows;
        filters: the scope's, touch facets included). ``sort``: ``search.ordering``.
        ``group``: ``"auto"`` (default) touch as grasps, ``"window"`` (or None) one Hit per
        item, ``"grasp"`` grasps of every sense, ``"moment"`` Moments. Embeds the query once."""
        where, g = Scope.of(**scope), check_group(group)
        kk = candidates(check_k(k), sort, where, self.store.schema)
        if g == "moment":  # embeds the query itself, once
            gap = DEFAULT_MOMENT_GAP if gap is None else gap
            return sort_hits(self.search_moments(query, kk, gap=gap, scope=where), sort, k)
        q = embed_query(self.space, query)
        with self.registry.pinned():  # one view of the senses for the whole question
            grouped = self.temporal.grouped(q, kk, where, g, pool, sort, k)  # grasp; auto: touch
            if grouped is not None:
                return grouped
            # group="window", or no touch sense in scope: the merged top k of one Ranker pass
            return sort_hits(self._rank_in(q, kk, where, transform=True), sort, k)

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
        return self._rank_in(q, k, Scope.of(**scope), transform)

    def _rank_in(self, q: np.ndarray, k: int, where: Scope, transform: bool) -> list[Hit]:
        """:meth:`rank` the (1, D) unit query ``q`` over the scope's senses and filters, hits
        marked with their match bar."""
        with self.registry.pinned():  # one view of the senses and tables for the question
            names = self.resolve_senses(where.senses)
            return mark_matches(self.rank(q, k, names, where.where(), transform=transform))

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
            item = s.validate(example, **options_for(s, options))
            q = as_unit_rows(s.embed([item]), self.space.dim, what="example")
        else:
            self.registry.search_sense(sense)
            q = as_unit_rows(vector, self.space.dim, what="example vector")
        where = Scope.of(**scope)
        if not where.senses:
            where = Scope.of(where, senses=[sense])
        return self._rank_in(q[:1], check_k(k), where, transform=False)  # unit rows, once

    def rank(
        self, q: np.ndarray, k: int, senses: Sequence[str], base: Where, **kw: Any
    ) -> list[Hit]:
        """The one ranked search path (:meth:`tactus_memory.search.ranking.Ranker.rank`): (1, D)
        unit query ``q``, the senses searched, ``base`` the non-sense conditions; keywords
        ``transform`` (apply each sense's query transform)."""
        return self.ranker.rank(q, k, senses, base, **kw)

    # ----------------------------------------------------------- reads
    def get_item(self, id: str, *, vector: bool = False) -> Item:  # noqa: A002
        """One stored item with ``raw`` decoded (by its sense when live, else as npy/text)."""
        cols = [*HIT_COLUMNS, "raw", "created", "orientation"] + (["vector"] if vector else [])
        rows = self.store.scan(Where().ids([id]).sql(), cols, limit=1).to_pylist()
        if not rows:
            raise NotFoundError(f"no item with id {id!r}")
        row = rows[0]
        s = self.registry.senses.get(row["sense"])
        if s is not None:
            raw = s.from_row(row)
        else:
            raw = bytes_to_array(row["raw"]) if row.get("raw") is not None else row.get("text")
        return item_from_row(row, raw)

    def sessions(self) -> list[SessionSummary]:
        """A summary per session (counts per sense, time span), sorted by id."""
        return self._summaries(None)

    def session(self, session: str) -> SessionSummary:
        out = self._summaries(Where().session(session).sql())
        if not out:
            raise NotFoundError(f"no session {session!r}")
        return out[0]

    def _summaries(self, where: str | None) -> list[SessionSummary]:
        return summarise(self.store.scan(where, ["session", "sense", "t", "t_end"]))

    def close(self) -> None:
        """Let background maintenance finish (the store needs no other closing)."""
        self.wait_for_maintenance()
        self.store.wait_for_cleanup()

    def __exit__(self, *exc: object) -> None:  # ``with``: __enter__ (self) from the base
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

    def reembed(self, sense: str, encoder: Sense, **kw: Any) -> Any:
        """Recompute every stored vector of ``sense`` with ``encoder`` from the stored raw
        inputs, swapped in one commit, resumable: :func:`tactus_memory.memory.reembed.reembed`
        (returns its ReembedReport; keywords ``batch``, ``on_batch``, ``on_rows``)."""
        from tactus_memory.memory.reembed import reembed

        return reembed(self, sense, encoder, **kw)


#: checked by the type checker (``make lint``): Memory implements the memory's contract
_CONTRACT: type[MemoryAPI] = Memory
