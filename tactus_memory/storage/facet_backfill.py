"""Touch facets for a store made before them (``tactus maintain --facets``): the facet columns
(:data:`~tactus_memory.storage.tables.FACET_COLUMNS`) added to the items table, each touch
row's computed from its stored window (the calibrated frames the touch sense keeps in
``raw``) with its sense's sensor profile (recorded in the sense's provenance); other rows get
nulls. One Lance schema-evolution commit (``add_columns``), so a run killed before it leaves
the store as it was (its files are removed by maintenance's orphan sweep) and running it
again does it all; a run on a store that has the columns changes nothing. Writes of this
process wait (the store's commit lock); run it with the store's servers stopped, as
``--sense-codes`` (a server that opened the store before keeps writing rows without facets).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import NotFoundError
from tactus_memory.senses.base import bytes_to_array
from tactus_memory.storage.tables import FACET_COLUMNS, facet_fields
from tactus_memory.touch.facets import facet_columns, window_facets
from tactus_memory.touch.profile import SensorProfile

if TYPE_CHECKING:
    import pyarrow as pa

    from tactus_memory.storage.store import Store

#: rows read and computed per batch (a 8x32x32 float16 window is 16 KB: 4096 rows ~64 MB)
FACET_BATCH = 4096


@dataclass
class FacetsReport:
    """What :func:`add_facets` did: ``added`` the columns (False: the store had them);
    ``rows`` in the table, ``touch_rows`` of them given facets; ``seconds`` the run."""

    uri: str
    added: bool
    rows: int
    touch_rows: int
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def touch_profiles(store: Store) -> dict[str, SensorProfile]:
    """Each touch sense's sensor profile, from the ``calibration`` of its recorded
    provenance (senses without one, e.g. a stand-in, get no facets)."""
    out = {}
    for row in store.sense_rows():
        if row.get("modality") != "touch":
            continue
        calibration = json.loads(row.get("provenance") or "{}").get("calibration")
        if calibration:
            out[row["name"]] = SensorProfile.from_dict(calibration)
    return out


def touch_taxels(store: Store) -> dict[str, int]:
    """Each touch sense's taxel count (``touch.facets.taxel_mask`` of its recorded profile):
    what a firmness band is relative to, for facets stored before they said it."""
    from tactus_memory.touch.facets import taxel_mask
    from tactus_memory.touch.regions import regions_of

    return {
        name: int(taxel_mask(p, regions_of(p), (int(p.shape[0]), int(p.shape[1]))).sum())
        for name, p in touch_profiles(store).items()
    }


def _facets_of(raw: bytes | None, profile: SensorProfile | None) -> dict[str, Any] | None:
    if raw is None or profile is None:
        return None
    window = np.asarray(bytes_to_array(raw), np.float32)
    if window.ndim != 3 or tuple(window.shape[1:]) != tuple(profile.shape):
        return None
    return facet_columns(window_facets(window[None], profile).row(0))


def add_facets(store: Store, *, on_batch: Callable[[int], None] | None = None) -> FacetsReport:
    """Add the facet columns to ``store``'s items (the module docstring says how and what a
    crash leaves). ``on_batch(rows)``: progress. Raises NotFoundError when the store has no
    items table."""
    import lance
    import pyarrow as pa

    t0 = time.perf_counter()
    if not store.exists:
        raise NotFoundError(f"no memory at {store.uri!r} (no items table)")
    store.integrity.require()
    profiles = touch_profiles(store)
    schema = pa.schema(facet_fields())
    done = touched = 0

    @lance.batch_udf(output_schema=schema)
    def facet_rows(batch: pa.RecordBatch) -> pa.RecordBatch:
        nonlocal done, touched
        cols: dict[str, list[Any]] = {c: [] for c in FACET_COLUMNS}
        raws = batch.column("raw").to_pylist()
        senses = batch.column("sense").to_pylist()
        for raw, sense in zip(raws, senses, strict=True):
            f = _facets_of(raw, profiles.get(sense))
            touched += f is not None
            for c in FACET_COLUMNS:
                cols[c].append(None if f is None else f[c])
        done += batch.num_rows
        if on_batch is not None:
            on_batch(done)
        return pa.RecordBatch.from_pydict(cols, schema=schema)

    with store._maintenance, store.commit_lock:
        store.reread_layout()
        ds = store.items.to_lance()
        if "facets" in ds.schema.names:
            seconds = round(time.perf_counter() - t0, 3)
            return FacetsReport(store.uri, False, ds.count_rows(), 0, seconds)
        ds.add_columns(facet_rows, read_columns=["raw", "sense"], batch_size=FACET_BATCH)
        rows = ds.count_rows()
        store.reread_layout()
    return FacetsReport(store.uri, True, rows, touched, round(time.perf_counter() - t0, 3))
