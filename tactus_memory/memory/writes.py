"""The write path of a memory: validate a write (:meth:`WritePath.prepare_write`), then embed
and store prepared writes in one LanceDB commit (:meth:`WritePath.commit_writes`).

``memory.prepare_write``, ``memory.commit_writes`` and ``memory.validate_item`` ARE these
methods; ``memory.add`` / ``add_many``, the group committer
(:mod:`tactus_memory.memory.group_commit`),
the service and recordings all write through them. Row-level helpers (batches, ids, the
Arrow table written): :mod:`tactus_memory.storage.rows`.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tactus_memory.errors import IdleWindowError, InvalidInputError
from tactus_memory.memory.places import Places
from tactus_memory.results import Stored
from tactus_memory.search.senses import SenseRegistry
from tactus_memory.spaces.base import Space
from tactus_memory.storage.rows import (
    PreparedWrite,
    check_batch,
    claim_ids,
    embed_groups,
    embed_isolated,
    options_for,
    resolve_shared_ids,
    writes_table,
)
from tactus_memory.storage.store import Store
from tactus_memory.where import DEFAULT_FRAME, validate_id, validate_source


@dataclass(eq=False)
class WritePath:
    """Validated, all-or-nothing writes into one store (under the memory's write lock)."""

    store: Store
    registry: SenseRegistry
    space: Space
    lock: threading.RLock
    places: Places

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
        items = list(items)
        batch = check_batch(len(items), t, t_end, meta, ids, position, frame)
        opts = options_for(s, options)
        canon, skipped = [], []
        for i, x in enumerate(items):
            try:
                canon.append(s.validate(x, **opts))
            except IdleWindowError:
                if not skip_idle:
                    raise
                skipped.append((i, "idle"))
        if skipped:
            batch = batch.without([i for i, _ in skipped])
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
        :func:`~tactus_memory.storage.rows.resolve_shared_ids`).
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
        if isolate:
            embed_isolated(live, self.space.dim)
            resolve_shared_ids(live)
        else:
            embed_groups(live, self.space.dim)
            all_ids = [i for w in live if w.batch.upsert for i in w.ids]
            if len(set(all_ids)) != len(all_ids):
                raise InvalidInputError("the same id appears in two writes of one commit")
        with self.lock:
            # embedded by an encoder the store no longer records (a re-embedding swapped the
            # sense meanwhile, maybe in another process): refused, never mixed
            swapped = self.registry.check_embedded_by([w.sense for w in live if w.error is None])
            for w in live:
                if w.sense.name in swapped and w.error is None:
                    if not isolate:
                        raise swapped[w.sense.name]
                    w.error = swapped[w.sense.name]
            replaced = claim_ids(self.store, live, isolate)  # under the lock: no racing writer
            ok = [w for w in live if w.error is None]
            if not ok:
                return [w.stored() for w in writes]
            self.places.fill(ok)  # under the lock: poses added meanwhile are seen
            before = self.store.version()
            self.store.write(
                writes_table(self.store.schema, ok), upsert=any(w.batch.upsert for w in ok)
            )
            self.registry.note_writes(before, ok, replaced)  # never raises: the rows are stored
        return [w.stored() for w in writes]

    def validate_item(self, sense: str, item: Any, options: Mapping[str, Any] | None = None) -> Any:
        """``item`` checked (and canonicalised) by the live ``sense``, as ``add`` would store
        it (the touch sense: calibrated, idle refused); ``add``/``add_many`` take the result as
        it is, without checking or calibrating it again."""
        s = self.registry.live_sense(sense)
        return s.validate(item, **options_for(s, options))
