"""The ``poses`` table (session trajectories) and the items' place columns in one store.

Stores created before places existed get the place columns (all null) when they are opened:
one metadata-only LanceDB commit (``add_columns``), so old items are simply unplaced until
poses arrive (then :meth:`tactus_memory.memory.places.Places.place_items` backfills them). Where
the store cannot be written, it is read as it is (``Store.present``): every item unplaced.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.storage.passes import announce_commit
from tactus_memory.storage.places import Placement, Trajectory
from tactus_memory.storage.store import POSES, Store
from tactus_memory.storage.tables import place_fields, poses_schema
from tactus_memory.where import Where

if TYPE_CHECKING:
    import pyarrow as pa

log = logging.getLogger(__name__)

#: the place columns written by a backfill (with ``id`` as the merge key)
PLACE_COLUMNS = ["x", "y", "z", "orientation", "frame", "placed"]


def add_place_columns(store: Store) -> bool:
    """Give an items table made before places its (null) place columns; True if it did."""
    if not store.exists:
        return False
    missing = [f for f in place_fields() if f.name not in store.items.schema.names]
    if not missing:
        return False
    try:
        with store.commit_lock:
            store.items.add_columns(missing)
    except Exception:  # noqa: BLE001  (read-only storage: read on, every item unplaced)
        log.warning("could not add the place columns to %s; its items read as unplaced", store.uri)
        return False
    store._schema = None  # the cached schema is stale now
    return True


class PoseStore:
    """Reads and writes of the ``poses`` table; trajectories cached per table version."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self._table: Any = None
        self._cache: dict[str, tuple[int, list[Trajectory]]] = {}
        self._lock = threading.Lock()
        self._writes = 0
        add_place_columns(store)
        if POSES in store._table_names():
            self._table = store.db.open_table(POSES)

    def _create(self) -> Any:
        if self._table is None:
            self._table = self.store.db.create_table(POSES, schema=poses_schema(), exist_ok=True)
        return self._table

    def version(self) -> int:
        return 0 if self._table is None else int(self._table.version)

    def read_latest(self) -> None:
        """The poses table at its latest version now (opened if another process made it)."""
        if self._table is None and POSES in self.store._table_names():
            self._table = self.store.db.open_table(POSES)
        if self._table is not None:
            self._table.checkout_latest()

    def write(
        self,
        session: str,
        t: np.ndarray,
        position: np.ndarray,
        orientation: np.ndarray | None,
        frame: str,
        source: str,
    ) -> None:
        """One append commit of checked poses (``t: (N,)``, ``position: (N, 3)``,
        ``orientation: (N, 4)`` or None)."""
        import pyarrow as pa

        n = t.shape[0]
        quats = (
            pa.nulls(n, pa.list_(pa.float64(), 4))
            if orientation is None
            else pa.FixedSizeListArray.from_arrays(pa.array(orientation.reshape(-1)), 4)
        )
        data = pa.table(
            {
                "session": [session] * n,
                "t": t,
                "x": position[:, 0],
                "y": position[:, 1],
                "z": position[:, 2],
                "orientation": quats,
                "frame": [frame] * n,
                "source": [source] * n,
            },
            schema=poses_schema(),
        )
        table = self._create()
        table.add(data)
        announce_commit()
        self._writes += 1
        if self.store.maintenance.maintain and self._writes % self.store.index.compact_every == 0:
            table.optimize()  # small appends (a stream of pose batches) into few fragments

    def rows(self, session: str, frame: str | None = None) -> pa.Table:
        """The session's poses (every column), in storage order."""
        import pyarrow as pa

        if self._table is None:
            return poses_schema().empty_table()
        where = Where().session(session).frame(frame).sql()
        tbl = self._table.search().where(where).limit(None).to_arrow()
        return tbl if tbl.num_rows else pa.Table.from_pylist([], schema=poses_schema())

    def trajectories(self, session: str) -> list[Trajectory]:
        """The session's trajectories, one per frame (cached until the table changes)."""
        version = self.version()
        with self._lock:
            hit = self._cache.get(session)
            if hit is not None and hit[0] == version:
                return hit[1]
        tbl = self.rows(session)
        out = []
        frames = np.array(tbl.column("frame").to_pylist(), dtype=object)
        for frame in sorted(set(frames)):
            sel = np.flatnonzero(frames == frame)
            part = tbl.take(sel)
            pos = np.column_stack([part.column(c).to_numpy() for c in "xyz"])
            quats = [q if q is not None else [np.nan] * 4 for q in part["orientation"].to_pylist()]
            ori = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
            out.append(Trajectory.from_rows(frame, part.column("t").to_numpy(), pos, ori))
        with self._lock:
            self._cache[session] = (version, out)
        return out

    def delete_session(self, session: str) -> int:
        """Delete a session's poses; returns how many there were."""
        if self._table is None:
            return 0
        where = Where().session(session).sql()
        n = int(self._table.count_rows(where))
        if n:
            self._table.delete(where)
        return n

    def set_places(self, ids: Sequence[str], place: Placement) -> None:
        """Rewrite the place columns of the item rows ``ids`` (one merge-insert commit)."""
        import pyarrow as pa

        cols = place.columns()
        data = pa.table({"id": pa.array(list(ids), pa.string()), **cols})
        items = self.store.items
        with self.store.commit_lock:
            items.merge_insert("id").when_matched_update_all().execute(data)
