"""The write path of a memory: validate a write (:meth:`WritePath.prepare_write`), then embed
and store prepared writes in one LanceDB commit (:meth:`WritePath.commit_writes`).

``memory.prepare_write``, ``memory.commit_writes`` and ``memory.validate_item`` ARE these
methods; ``memory.add`` / ``add_many``, the group committer
(:mod:`tactus_memory.memory.group_commit`),
the service and recordings all write through them. The path a write takes: this module ->
the sense (``validate_many``, ``embed``, ``to_row``) -> storage (the batch checks and the
Arrow table, :mod:`tactus_memory.storage.rows`; the commit, :class:`Store`); storage never
calls back into the sense.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tactus_memory.errors import IdConflictError, InvalidInputError
from tactus_memory.memory.places import Places
from tactus_memory.names import validate_id
from tactus_memory.results import Stored
from tactus_memory.search.captions import Captions
from tactus_memory.senses.base import Sense
from tactus_memory.senses.stored import SenseRegistry
from tactus_memory.spaces.base import Space
from tactus_memory.storage.rows import PreparedWrite, check_batch, options_for, writes_table
from tactus_memory.storage.store import Store
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import DEFAULT_FRAME, validate_source


@dataclass(eq=False)
class WritePath:
    """Validated, all-or-nothing writes into one store (under the memory's write lock)."""

    store: Store
    registry: SenseRegistry
    space: Space
    lock: threading.RLock
    places: Places

    def __post_init__(self) -> None:
        #: touch windows' caption embeddings, added before their rows (search.captions)
        self.captions = Captions(self.store, self.space)

    def prepare_write(
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
        position: Any = None,
        frame: str = DEFAULT_FRAME,
        skip_idle: bool = True,
    ) -> PreparedWrite:
        """Validate one write (``add_many``'s arguments) without embedding or storing it;
        ``position``: one ``(x, y, z)`` for every item or one per item (None: placed from the
        session's poses), in ``frame``. An item the sense finds idle (a touch window with no
        contact, ``IdleWindowError``) is skipped and reported (``PreparedWrite.skipped``: its
        index, ``"idle"``), the rest are written; ``skip_idle=False`` raises instead.

        Raises the typed error naming the problem; the result goes to :meth:`commit_writes`,
        alone or with the writes of other sessions (group commit,
        ``tactus_memory.memory.group_commit``).
        """
        session = validate_id(session, "session id")
        source = validate_source(source)
        s = self.registry.live_sense(sense)
        # a (B, ...) array stays one array: the sense checks it in one pass (validate_many)
        items = items if isinstance(items, np.ndarray) else list(items)
        batch = check_batch(len(items), t, t_end, meta, ids, position, frame)
        canon, idle = s.validate_many(items, skip_idle=skip_idle, **options_for(s, options))
        skipped = [(i, "idle") for i in idle]
        if skipped:
            batch = batch.without(idle)
        return PreparedWrite(session, s, canon, batch, source, skipped=skipped)

    def commit_writes(
        self, writes: Sequence[PreparedWrite], *, isolate: bool = False
    ) -> list[Stored]:
        """Embed prepared writes (ONE ``embed`` call per sense across all of them) and store
        them all in ONE LanceDB commit; returns each write's ids, in order.

        All-or-nothing: if embedding or the commit fails nothing is written (vectors already
        computed stay on the writes). Appends are one append; if any write is an upsert, all
        rows go in one merge-insert. ``isolate`` (the group committer): a write whose
        embedding fails or whose id clashes (with another write of this commit, or another
        session's row) gets its ``error`` and is left out, the rest still commit once (an
        identical repeat of an id is written once,
        :func:`resolve_shared_ids`).
        Rows embedded by an encoder the store no longer records for their sense (a
        re-embedding swapped it, here or in another process) are refused with
        SenseSwappedError (``isolate``: those writes' ``error``); the sense is rebuilt from
        the store's record when it can be. Once the rows are stored nothing raises: a failing
        step after the commit is logged and its caches dropped, so no caller retries (and
        duplicates) a stored write.
        """
        live = [w for w in writes if len(w)]
        if not live:
            return [w.stored() for w in writes]
        if isolate:  # a write that already failed its embedding (the committer's) stays out
            embed_isolated([w for w in live if w.error is None], self.space.dim)
            resolve_shared_ids(live)
        else:
            embed_groups(live, self.space.dim)
            all_ids = [i for w in live if w.batch.upsert for i in w.ids]
            if len(set(all_ids)) != len(all_ids):
                raise InvalidInputError("the same id appears in two writes of one commit")
        # the captions of touch windows the store lacks, before the rows (search.captions)
        self.captions.add([e for w in live if w.error is None for e in w.extras])
        with self.lock:
            # embedded by an encoder the store no longer records (a re-embedding swapped the
            # sense meanwhile, maybe in another process): refused, never mixed
            swapped = self.registry.check_embedded_by([w.sense for w in live if w.error is None])
            for w in live:
                if w.sense.name in swapped and w.error is None:
                    if not isolate:
                        raise swapped[w.sense.name]
                    w.error = swapped[w.sense.name]
            ok = [w for w in live if w.error is None]
            self.places.fill(ok)  # under the lock: poses added meanwhile are seen
            # under the lock: no racing writer
            replaced = claim_ids(self.store, live, isolate, self.store.schema)
            ok = [w for w in live if w.error is None and w.written]
            if not ok:
                return [w.stored() for w in writes]
            before = self.store.version()
            if isolate:
                commits = self._commit_split(ok)
            else:  # all or nothing: one commit
                self.store.write(
                    writes_table(self.store.schema, ok), upsert=any(w.batch.upsert for w in ok)
                )
                commits = 1
            stored = [w for w in ok if w.error is None]
            # never raises: the rows are stored
            self.registry.note_writes(before, stored, replaced, commits)
        return [w.stored() for w in writes]

    def _commit_split(self, writes: Sequence[PreparedWrite]) -> int:
        """The group committer's commit: the rows of generated ids in one append, the rows of
        explicit ids (upserts) in one merge-insert on ``id`` after it, so that an explicit id
        in a tick never makes the whole tick a merge-insert (its join reads every stored
        ``id``: 3-4x the append's time at 10,000 rows, issue 48). A failing append fails
        every write (raised); a failing merge-insert fails only the upserts (their
        ``error``), the append stays stored and acknowledged. Returns the commits made."""
        schema = self.store.schema
        appends = [w for w in writes if not w.batch.upsert]
        upserts = [w for w in writes if w.batch.upsert]
        commits = 0
        if appends:
            self.store.write(writes_table(schema, appends), upsert=False)
            commits += 1
        if upserts:
            try:
                self.store.write(writes_table(schema, upserts), upsert=True)
            except Exception as exc:  # noqa: BLE001  (these writes fail alone; the append stays)
                if not appends:
                    raise
                for w in upserts:
                    w.error = exc
            else:
                commits += 1
        return commits

    def validate_item(self, sense: str, item: Any, options: Mapping[str, Any] | None = None) -> Any:
        """``item`` checked (and canonicalised) by the live ``sense``, as ``add`` would store
        it (the touch sense: calibrated, idle refused); ``add``/``add_many`` take the result as
        it is, without checking or calibrating it again."""
        s = self.registry.live_sense(sense)
        return s.validate(item, **options_for(s, options))


def embed_groups(
    writes: Sequence[PreparedWrite],
    dim: int,
    embed: Callable[[Sense, list[Any]], np.ndarray] | None = None,
) -> None:
    """Embed the writes that have no vectors yet: ONE ``embed`` call per sense across all of
    them (``embed(sense, items)``, default ``sense.embed(items)``; the group committer's
    encoder process passes its own); each write gets its slice of (n, ``dim``) unit rows."""
    by_sense: dict[str, list[PreparedWrite]] = {}
    for w in writes:
        if w.vectors is None:
            by_sense.setdefault(w.sense.name, []).append(w)
    for name, group in by_sense.items():
        canon = [x for w in group for x in w.canon]
        sense = group[0].sense
        raw = sense.embed(canon) if embed is None else embed(sense, canon)
        vectors = as_unit_rows(raw, dim, what=f"{name} embedding")
        if vectors.shape[0] != len(canon):
            raise InvalidInputError(
                f"sense {name!r} returned {vectors.shape[0]} vectors for {len(canon)}"
            )
        at = 0
        for w in group:
            w.vectors = vectors[at : at + len(w)]
            w.extras = [sense.to_row(x) for x in w.canon]  # the sense's columns, once
            at += len(w)


def embed_isolated(writes: Sequence[PreparedWrite], dim: int) -> None:
    """:func:`embed_groups`, but a failing embedding fails only its own write: when a sense's
    batch call raises, that sense's writes are embedded one by one and each culprit gets the
    exception as its ``error`` (no write is committed here, so nothing is written twice)."""
    try:
        embed_groups(writes, dim)
    except Exception:  # noqa: BLE001  (isolated below, write by write)
        for w in writes:
            if w.vectors is None:
                try:
                    embed_groups([w], dim)
                except Exception as exc:  # noqa: BLE001  (this write's own failure)
                    w.error = exc


def _payload(w: PreparedWrite, i: int) -> tuple[Any, ...]:
    """What an item id stores but its vector and ``created``: a repeat of it is idempotent."""
    row = w.sense.to_row(w.canon[i])
    b = w.batch
    return (w.session, w.sense.name, w.source, b.t[i], b.t_end[i], b.meta[i], sorted(row.items()))


def resolve_shared_ids(writes: Sequence[PreparedWrite]) -> None:
    """Two writes of one commit naming the same item id (say two clients retrying the same
    note in one tick): the later one is an idempotent repeat when its session, sense and
    payload match the earlier row (its row is marked ``dup`` and written once), else it fails
    alone with :class:`IdConflictError`. The rest of the commit is not affected."""
    first: dict[str, tuple[PreparedWrite, int]] = {}
    for w in writes:
        w.dup.clear()  # (re-)resolved from scratch: a write may have failed since
        if w.error is not None or not w.batch.upsert:
            continue  # generated ids never clash
        for i, item_id in enumerate(w.ids):
            seen = first.get(item_id)
            if seen is not None and _payload(*seen) != _payload(w, i):
                w.error = IdConflictError(
                    f"item id {item_id!r} is written by two requests at once with different "
                    "content (or session, sense); the other one was stored, send this one again "
                    "to replace it"
                )
                w.dup.clear()
                break
            if seen is not None:
                w.dup.add(i)
        if w.error is None:
            for i, item_id in enumerate(w.ids):
                first.setdefault(item_id, (w, i))


#: columns an item's stored row is compared on with a repeat of its id (all but the vector,
#: ``created`` and ``episode``): equal, the repeat is acknowledged and not written again
_COMPARED_OUT = frozenset({"vector", "created", "episode"})


def claim_ids(
    store: Store, writes: Sequence[PreparedWrite], isolate: bool, schema: Any = None
) -> dict[int, int]:
    """Rows each upsert replaces (of its own session and sense), by ``id(write)``, read in
    ONE scan for every upsert of the commit. An id of another session or sense raises
    IdConflictError (``isolate``: that write's ``error``). With ``schema`` (the items table's;
    the writes embedded and placed), an item whose id the store already holds with exactly
    this content is marked ``unchanged``: acknowledged, not written again (two clients
    re-sending one note cost no commit).
    Call it under the memory's commit lock, just before the store write."""
    replaced: dict[int, int] = {}
    upserts = [w for w in writes if w.batch.upsert and w.error is None]
    if not upserts:
        return replaced
    columns = [] if schema is None else [n for n in schema.names if n not in _COMPARED_OUT]
    stored = store.rows_by_id(sorted({i for w in upserts for i in w.ids}), columns)
    for w in upserts:
        if w.error is not None:  # (a write failed meanwhile: resolved again below)
            continue
        w.unchanged.clear()
        rows = {i: stored[i] for i in w.ids if i in stored}
        try:
            check_owned(list(rows.values()), w.session, w.sense.name)
        except IdConflictError as exc:
            if not isolate:
                raise
            w.error = exc
            resolve_shared_ids(writes)  # a repeat of its ids is no longer a repeat
            continue
        if rows and schema is not None:
            mine = writes_table(schema, [_whole(w)]).select(columns).to_pylist()
            for i, row in enumerate(mine):
                if rows.get(row["id"]) == row:
                    w.unchanged.add(i)
        replaced[id(w)] = sum(
            1 for i, item_id in enumerate(w.ids) if item_id in rows and i not in w.left_out
        )
    return replaced


def check_owned(rows: Sequence[dict[str, Any]], session: str, sense: str) -> None:
    """Raise IdConflictError, naming the first offending id, when a stored row of an
    upsert's ids belongs to another session or another sense: an upsert never overwrites or
    moves another session's row."""
    for row in rows:
        if row["session"] != session or row["sense"] != sense:
            raise IdConflictError(
                f"item id {row['id']!r} already belongs to another session or sense (not "
                f"{sense!r} in session {session!r}); use another id, or delete that item first"
            )


def _whole(w: PreparedWrite) -> PreparedWrite:
    """``w`` with every row (none left out): the rows it would write, in order."""
    return replace(w, dup=set(), unchanged=set())
