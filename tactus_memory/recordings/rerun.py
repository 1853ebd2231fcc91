"""Export a session to a Rerun recording (``.rrd``), to open in the Rerun viewer.

On the timeline ``session_time`` (the session clock, aligned with the memory's clock
offsets), one entity per stream:

* ``touch/<source>``: each touch window as a heat-map image of its K frames side by side,
  drawn by :func:`tactus_memory.touch.render.window_rgba` (the page's renderer and colour
  scale; non-taxel pixels transparent), logged at the window's start;
* ``text/<source>``: notes as text logs;
* ``image/<source>``: stored camera images, when the image sense kept the pixels;
* ``moments/query``: with ``query``, each moment of that query (``Memory.search_moments``) as
  a text-log annotation at the moment's start (level WARN, with its score and senses) and
  ``moments/score`` as a scalar that is the moment's score over its span and 0 outside.

* ``places/trajectory/<frame>``: the session's poses as a 3-D line strip (static) and
  ``places/robot/<frame>`` as a 3-D point moving along it on the timeline;
* ``places/items``: every placed item as a 3-D point (labelled with its sense and text) at
  its time, and ``places/hits`` the moments of ``query`` that have a place, at theirs.

``rerun-sdk`` is imported lazily (``pip install 'tactus-memory[recordings]'``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel

from tactus_memory.names import validate_id
from tactus_memory.senses.base import bytes_to_array
from tactus_memory.where import Where

if TYPE_CHECKING:  # recordings take a memory; the memory knows nothing of them
    from tactus_memory.memory.main import Memory


TIMELINE = "session_time"
APPLICATION_ID = "tactus-memory"
#: columns read back for the export (the items themselves come from the timeline)
SCAN_COLUMNS = ("id", "raw")
#: moments of a query exported with --query
MOMENTS_K = 20
#: pixels per taxel in the exported heat maps: 1 keeps a K=8 window at 32 x 263 RGBA (34 kB;
#: a 10-minute 30 Hz session is 2250 windows); the viewer scales images up itself
EXPORT_SCALE = 1
#: Rerun keeps durations as int64 nanoseconds: |t| beyond this many seconds cannot be placed
MAX_RERUN_SECONDS = 9.2e9


class ExportSummary(BaseModel):
    session: str
    path: str
    entities: dict[str, int]  # entity path -> rows logged
    moments: int
    skipped: dict[str, int] = {}  # reason -> items not exported


#: the touch facets logged as scalar series beside each touch stream (facets/<stream>/<name>)
FACET_SCALARS = ("force", "area", "peak", "spread")


def _entity(part: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", part) or "default"


def export_rerun(
    memory: Memory,
    session: str,
    path: str | Path,
    *,
    query: str | None = None,
    moments: int = MOMENTS_K,
) -> ExportSummary:
    """Write ``session`` to ``path`` (``.rrd``); NotFoundError for an unknown session."""
    try:
        import rerun as rr
    except ImportError as exc:
        raise ImportError(
            f"exporting to Rerun needs rerun-sdk ({exc}); pip install 'tactus-memory[recordings]'"
        ) from exc
    from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile
    from tactus_memory.touch.render import window_rgba

    session = validate_id(session, "session id")
    # NotFoundError for an unknown session; aligned times
    items: list[Any] = memory.timeline(session)
    infos = memory.sense_info()
    modality = {s.name: s.modality for s in infos}
    # each touch sense's sensor (its frame shape and taxel layout), as its provenance recorded
    profiles = {
        s.name: SensorProfile.from_dict(s.provenance["calibration"])
        for s in infos
        if isinstance(s.provenance.get("calibration"), dict)
    }
    found = memory.search_moments(query, k=moments, session=session) if query else []
    table = memory.store.scan(Where().session(session).sql(), list(SCAN_COLUMNS))
    raw = dict(zip(table.column("id").to_pylist(), table.column("raw").to_pylist(), strict=True))

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"{session}")
    rec.save(str(out))
    counts: dict[str, int] = {}
    skipped: dict[str, int] = {}

    def log(entity: str, t: float, value: Any) -> None:
        if not abs(t) <= MAX_RERUN_SECONDS:  # the store takes any finite time; Rerun does not
            why = f"time beyond Rerun's range (|t| > {MAX_RERUN_SECONDS:g} s)"
            skipped[why] = skipped.get(why, 0) + 1
            return
        rec.set_time(TIMELINE, duration=float(t))
        rec.log(entity, value)
        counts[entity] = counts.get(entity, 0) + 1

    try:
        for it in items:
            kind = modality.get(it.sense, "")
            stream = _entity(it.source or it.sense)
            if kind == "touch" and raw.get(it.id) is not None:
                window = bytes_to_array(raw[it.id]).astype(np.float32)  # (K, H, W)
                profile = profiles.get(it.sense, STAG_GLOVE)
                log(
                    f"touch/{stream}",
                    it.t_aligned,
                    rr.Image(window_rgba(window, scale=EXPORT_SCALE, profile=profile)),
                )
                for name in FACET_SCALARS if it.facets else ():  # the window's facets
                    value = it.facets.get(name)
                    if value is not None:
                        log(f"facets/{stream}/{name}", it.t_aligned, rr.Scalars(float(value)))
            elif kind == "text" or (it.text is not None and kind != "image"):
                log(f"text/{stream}", it.t_aligned, rr.TextLog(it.text or "", level="INFO"))
            elif kind == "image" and raw.get(it.id) is not None:
                log(f"image/{stream}", it.t_aligned, rr.Image(bytes_to_array(raw[it.id])))
        for m in found:
            label = (
                f"{query!r}: score {m.score:.2f}, {m.t:.2f}-{m.t_end:.2f} s, "
                f"senses {', '.join(m.senses)}"
            )
            log("moments/query", m.t, rr.TextLog(label, level="WARN"))
            log("moments/score", max(m.t - 1e-3, 0.0), rr.Scalars(0.0))
            log("moments/score", m.t, rr.Scalars(float(m.score)))
            log("moments/score", m.t_end, rr.Scalars(float(m.score)))
            log("moments/score", m.t_end + 1e-3, rr.Scalars(0.0))
        if found:
            rec.log("moments/query_text", rr.TextDocument(f"query: {query}"), static=True)
        _places(rr, rec, memory, session, items, found, log, counts)
    finally:
        rec.flush()
        rec.disconnect()
    return ExportSummary(
        session=session, path=str(out), entities=counts, moments=len(found), skipped=skipped
    )


def _places(
    rr: Any, rec: Any, memory: Memory, session: str, items: list[Any], found: list[Any],
    log: Any, counts: dict[str, int],
) -> None:  # fmt: skip
    """The trajectory (static strip + the robot's point on the timeline), the placed items
    and the placed moments of the query as 3-D points."""
    for tr in memory.trajectory(session):
        pos = np.asarray(tr.position, dtype=np.float32)  # (N, 3)
        t = np.asarray(tr.t, dtype=np.float64)  # (N,)
        ok = np.abs(t) <= MAX_RERUN_SECONDS
        frame = _entity(tr.frame)
        rec.log(f"places/trajectory/{frame}", rr.LineStrips3D([pos]), static=True)
        rec.send_columns(
            f"places/robot/{frame}",
            indexes=[rr.TimeColumn(TIMELINE, duration=t[ok])],
            columns=rr.Points3D.columns(positions=pos[ok]),
        )
        counts[f"places/robot/{frame}"] = int(ok.sum())
    for it in items:
        if it.position is not None:
            label = f"{it.sense}: {it.text}" if it.text else it.sense
            log("places/items", it.t_aligned, rr.Points3D([it.position], labels=[label]))
    for m in found:
        if m.position is not None:
            label = f"score {m.score:.2f}"
            point = rr.Points3D([m.position], labels=[label], radii=[0.2], colors=[(255, 80, 0)])
            log("places/hits", m.t, point)
