"""Stream evaluation: the touch memory scored the way it is used (``tactus eval --stream``).

Whole held-out recordings (every frame, the idle ones before and between grasps included) are
laid end to end as ONE session on one clock (:data:`RECORDING_GAP_S` seconds apart), cut by the
library's stream windowing (:func:`tactus_memory.touch.windows.cut_windows`, the same cut as the
WebSocket stream and recording ingest) and written to a real :class:`~tactus_memory.Memory`
(real LanceDB, the real space, the checkpoint as the ``touch`` sense). Then natural questions
(:data:`QUERIES_PATH`, several phrasings per class, none a training template) are asked
through the memory's own search path, and scored against the recording each window came from:

* retrieval, text -> touch: R@1, R@5 and MRR of the first window of the named object, per
  class and overall (mean over queries);
* the match bar (calibrated score >= ``MATCH_Z["touch"]``, the bar ``last``/``count`` use):
  how often a window of *another* object passes it, how often an *idle* window passes it,
  and the precision of what passes;
* ``memory.last`` (is the returned moment inside the named object's recording?) and
  ``memory.count`` (the session holds exactly one recording per class: truth is 1; 0 for a
  class with no recording here, e.g. the empty hand in the blindfolded split).

Two storage modes are scored, both with the same windows: ``served`` stores what the stream
windowing keeps (idle windows are not embedded: the policy of ``touch/windows.py``) and
``all_windows`` embeds every window, idle ones included (the behaviour before the idle rule),
which is what the idle pass rate is measured on.

``groups=(None, "grasp")`` (``--group grasp``) also scores each mode grasp-grouped
(``<mode>_grasp``; ``<mode>_grasp_<pool>`` for each other pool of ``pools``): the search,
``last`` and ``count`` rank grasps (``group="grasp"``, :mod:`tactus_memory.search.grasps`); a
grasp is
right when every window it pools comes from the queried object's recording, and the match-bar
rates are over the grasps the search returned.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.search.grasps import POOLS
from tactus_memory.touch.targets import class_phrases
from tactus_memory.touch.windows import cut_windows

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space
    from tactus_memory.training.data import StagData

#: the natural queries, one list of phrasings per STAG class (written for this evaluation)
QUERIES_PATH = Path(__file__).parent / "queries" / "stream_queries.json"
#: stream windowing of the evaluation: K = 8 frames (the shipped model's K), a new window every
#: 4 frames (~0.13 s at the glove's ~30 Hz), as a live stream would be cut
STREAM_WINDOW = 8
STREAM_STRIDE = 4
#: seconds between consecutive recordings in the session: larger than the occurrence merge gap
#: (temporal.DEFAULT_MERGE_GAP = 2 s), so two recordings are never one occurrence
RECORDING_GAP_S = 10.0
SESSION = "stream-eval"
RECALL_AT = (1, 5)
MODES = ("served", "all_windows")
#: how results are grouped: None (windows) or "grasp"; a grouped mode's key is MODE_grasp
GROUPS = (None, "grasp")


@dataclass
class StreamSet:
    """The windows of one evaluation session. Per window (Wn,): ``obj`` class name,
    ``recording`` name, ``t``/``t_end`` on the session clock, ``idle`` (the windowing's flag),
    ``labelled`` (holds a frame the dataset labels as a valid grasp); ``frames`` (Wn, K, 32, 32)
    raw; ``spans`` maps each recording to its (start, end) on the session clock."""

    frames: np.ndarray
    t: np.ndarray
    t_end: np.ndarray
    idle: np.ndarray
    labelled: np.ndarray
    obj: list[str]
    recording: list[str]
    spans: dict[str, tuple[float, float]]
    rec_object: dict[str, str]

    def __len__(self) -> int:
        return int(self.frames.shape[0])


def load_queries(path: str | Path | None = None) -> dict[str, list[str]]:
    """class name -> natural phrasings (the JSON file's ``queries``)."""
    p = Path(path) if path is not None else QUERIES_PATH
    try:
        raw = json.loads(p.read_text())
        queries = raw["queries"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInputError(f"stream queries {p}: {exc}") from exc
    out: dict[str, list[str]] = {}
    for name, qs in queries.items():
        if not isinstance(qs, list) or not qs or not all(isinstance(q, str) and q for q in qs):
            raise InvalidInputError(f"stream queries {p}: {name!r} needs a list of strings")
        out[str(name)] = [str(q) for q in qs]
    return out


def template_collisions(queries: dict[str, list[str]]) -> list[str]:
    """Queries equal (case-insensitively) to a training phrase of any class: must be empty."""
    templates = {p.lower().strip() for c in queries for p in class_phrases(c)}
    return [q for qs in queries.values() for q in qs if q.lower().strip() in templates]


def build_stream(
    data: StagData,
    recordings: Sequence[int],
    *,
    window: int = STREAM_WINDOW,
    stride: int = STREAM_STRIDE,
    span: int | None = None,
) -> StreamSet:
    """Every frame of ``recordings`` (ids, in this order) -> one session's windows."""
    frames, t, t_end, idle, labelled, obj, rec = [], [], [], [], [], [], []
    spans: dict[str, tuple[float, float]] = {}
    rec_object: dict[str, str] = {}
    clock = 0.0
    for r in recordings:
        m = np.flatnonzero(data.recording_id == r)
        if m.size == 0:
            raise InvalidInputError(f"recording {r} has no frames in this data")
        m = m[np.argsort(data.frame[m], kind="stable")]
        ts = data.ts[m] - data.ts[m].min() + clock
        w = cut_windows(data.pressure[m], ts, window=window, stride=stride, span=span)
        name = data.recordings[r]
        cls = data.objects[int(data.object_id[m[0]])]
        valid = data.valid[m]
        labelled += [bool(valid[s0 : s0 + (span or window)].any()) for s0 in w.start]
        frames.append(w.frames)
        t.append(w.t)
        t_end.append(w.t_end)
        idle.append(w.idle)
        obj += [cls] * len(w)
        rec += [name] * len(w)
        spans[name] = (float(ts.min()), float(ts.max()))
        rec_object[name] = cls
        clock = float(ts.max()) + RECORDING_GAP_S
    if not frames or sum(len(f) for f in frames) == 0:
        raise InvalidInputError("no windows: recordings are shorter than one window")
    return StreamSet(
        frames=np.concatenate(frames),
        t=np.concatenate(t),
        t_end=np.concatenate(t_end),
        idle=np.concatenate(idle),
        labelled=np.asarray(labelled, dtype=bool),
        obj=obj,
        recording=rec,
        spans=spans,
        rec_object=rec_object,
    )


def _mean(xs: Sequence[float]) -> float | None:
    return float(np.mean(xs)) if len(xs) else None


def _rate(num: int, den: int) -> float | None:
    return num / den if den else None


def _store(memory: Any, stream: StreamSet, idx: np.ndarray) -> list[str]:
    """Write the windows ``idx`` to ``memory`` (session SESSION); their ids."""
    return memory.add_many(
        SESSION,
        "touch",
        list(stream.frames[idx]),
        t=[float(x) for x in stream.t[idx]],
        t_end=[float(x) for x in stream.t_end[idx]],
        meta=[
            {
                "object": stream.obj[i],
                "recording": stream.recording[i],
                "idle": bool(stream.idle[i]),
            }
            for i in idx
        ],
        # the "raw" mode stores idle windows on purpose: what the idle rule prevents is measured
        options={"keep_idle": True},
    )


def _score_mode(
    memory: Any,
    stream: StreamSet,
    idx: np.ndarray,
    ids: list[str],
    queries: dict[str, list[str]],
    bar: float,
    group: str | None = None,
    pool: str = "mean",
) -> dict[str, Any]:
    """Ask every query of the windows ``idx`` stored as ``ids`` (by window, or by grasp with
    ``group="grasp"``) and score."""
    from tactus_memory.limits import MAX_K

    where = dict(zip(ids, idx.tolist(), strict=True))  # stored id -> window index

    def label(h: Any) -> tuple[str | None, bool]:
        """(object of the hit, or None when its windows mix objects; is it idle)."""
        members = [where[i] for i in (getattr(h, "ids", None) or [h.id])]
        objs = {stream.obj[i] for i in members}
        return (objs.pop() if len(objs) == 1 else None), bool(stream.idle[members].all())

    ask = {"session": SESSION, "senses": ["touch"], "group": group, "pool": pool}
    k = min(len(idx), MAX_K)
    present = set(stream.rec_object.values())
    per_class: dict[str, dict[str, Any]] = {}
    rr_all, r_all = [], {n: [] for n in RECALL_AT}
    other_pass = other_n = idle_pass = idle_n = rel_pass = all_pass = 0
    last_ok, count_err, count_exact, absent_clean = [], [], [], []
    n_idle_kept = int(stream.idle[idx].sum())
    for cls, qs in queries.items():
        if cls not in present:
            # a class with no recording here: nothing should match (last None, count 0)
            for q in qs:
                occ = memory.count(q, **ask)
                absent_clean.append(occ == 0)
                hits = memory.search(q, k=k, **ask)
                idle = [label(h)[1] for h in hits]
                other_pass += sum(h.score >= bar and not i for h, i in zip(hits, idle, strict=True))
                idle_pass += sum(h.score >= bar and i for h, i in zip(hits, idle, strict=True))
                other_n += len(idx) - n_idle_kept if group is None else idle.count(False)
                idle_n += n_idle_kept if group is None else idle.count(True)
            continue
        rrs, rs = [], {n: [] for n in RECALL_AT}
        for q in qs:
            hits = memory.search(q, k=k, **ask)
            labels = [label(h) for h in hits]
            ranks = [i for i, (obj, _) in enumerate(labels) if obj == cls]
            rr = 1.0 / (ranks[0] + 1) if ranks else 0.0
            rrs.append(rr)
            for n in RECALL_AT:
                rs[n].append(float(bool(ranks) and ranks[0] < n))
            for h, (obj, idle) in zip(hits, labels, strict=True):
                if h.score < bar:
                    continue
                all_pass += 1
                if idle:
                    idle_pass += 1  # an idle hand is never "holding a ...", whichever object
                elif obj == cls:
                    rel_pass += 1
                else:
                    other_pass += 1
            if group is None:
                other_n += int(sum(1 for i in idx if stream.obj[i] != cls and not stream.idle[i]))
                idle_n += n_idle_kept
            else:  # over the grasps returned
                other_n += sum(1 for obj, idle in labels if obj != cls and not idle)
                idle_n += sum(1 for _, idle in labels if idle)
            moment = memory.last(q, **ask)
            rec = [r for r, c in stream.rec_object.items() if c == cls]
            ok = False
            if moment is not None:
                for r in rec:
                    a, b = stream.spans[r]
                    ok = ok or (moment.t <= b and moment.t_end >= a)
            last_ok.append(float(ok))
            c = memory.count(q, **ask)
            count_err.append(abs(c - len(rec)))
            count_exact.append(float(c == len(rec)))
        per_class[cls] = {
            "queries": len(qs),
            "mrr": _mean(rrs),
            **{f"r@{n}": _mean(rs[n]) for n in RECALL_AT},
        }
        rr_all += rrs
        for n in RECALL_AT:
            r_all[n] += rs[n]
    return {
        "group": group,
        "pool": pool if group else None,
        "windows_stored": int(len(idx)),
        "idle_windows_stored": n_idle_kept,
        "queries_scored": len(rr_all),
        "mrr": _mean(rr_all),
        **{f"r@{n}": _mean(r_all[n]) for n in RECALL_AT},
        "match_bar": bar,
        "match_other_object_rate": _rate(other_pass, other_n),
        "match_idle_rate": _rate(idle_pass, idle_n),
        "match_precision": _rate(rel_pass, all_pass),  # over queries of present classes
        "last_correct": _mean(last_ok),
        "count_exact": _mean(count_exact),
        "count_mean_abs_error": _mean([float(e) for e in count_err]),
        "absent_class_count_zero": _mean([float(x) for x in absent_clean]),
        "per_class": per_class,
    }


def leakage(meta: dict[str, Any], recordings: list[str], fingerprint: str | None) -> dict[str, Any]:
    """Were the scored recordings in the checkpoint's training data? (``overlap`` / ``clean``
    when the checkpoint's data fingerprint equals ``fingerprint``, else ``unknown``)."""
    if not fingerprint or meta.get("data_fingerprint") != fingerprint:
        return {"status": "unknown", "reason": "training data fingerprint differs or is absent"}
    held = set(meta.get("metrics", {}).get("heldout", {}).get("recordings_named", []) or [])
    seen = [r for r in recordings if r not in held]
    return {
        "status": "overlap" if seen else "clean",
        "trained_on": len(seen),
        "scored": len(recordings),
    }


def stream_markdown(result: dict[str, Any]) -> str:
    """A short markdown section of one stream evaluation (for ``--report``)."""
    lines = [
        "## Stream evaluation (natural queries over whole recordings)",
        "",
        f"checkpoint `{result['checkpoint']}`, {result['n_recordings']} recordings, "
        f"{result['windows']} windows ({result['idle_windows']} idle), "
        f"{result['n_queries']} queries; leakage: {result['leakage']['status']}",
        "",
        "| mode | R@1 | R@5 | MRR | other object passes bar | idle passes bar "
        "| bar precision | last correct | count exact |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def f(x: Any) -> str:
        return "-" if x is None else f"{x:.3f}"

    for mode in [k for k in result if k.split("_grasp")[0] in MODES]:
        m = result.get(mode)
        if not m or "mrr" not in m:
            continue
        lines.append(
            f"| {mode} | {f(m['r@1'])} | {f(m['r@5'])} | {f(m['mrr'])} "
            f"| {f(m['match_other_object_rate'])} | {f(m['match_idle_rate'])} "
            f"| {f(m['match_precision'])} | {f(m['last_correct'])} | {f(m['count_exact'])} |"
        )
    served = result.get("served", {}).get("per_class", {})
    if served:
        lines += ["", "| class (served) | R@1 | R@5 | MRR |", "| --- | --- | --- | --- |"]
        for cls, m in sorted(served.items()):
            lines.append(f"| {cls} | {f(m['r@1'])} | {f(m['r@5'])} | {f(m['mrr'])} |")
    return "\n".join(lines) + "\n"


def run_stream_eval(
    checkpoint: str | Path | None,
    data: StagData,
    holdout: str,
    *,
    limit: int = 0,
    queries_path: str | Path | None = None,
    span: int | None = None,
    space: Space | None = None,
    groups: Sequence[str | None] = (None,),
    pools: Sequence[str] = ("mean",),
) -> dict[str, Any]:
    """The whole stream evaluation from loaded data: the recordings ``holdout`` names (the
    training grammar, e.g. ``one-per-object@blindfolded``; the first ``limit`` when > 0)."""
    from tactus_memory.training.train import holdout_recordings

    try:
        recs = holdout_recordings(data, holdout)
    except ValueError as exc:
        raise InvalidInputError(str(exc)) from exc
    if not recs:
        raise InvalidInputError(f"holdout {holdout!r} names no recordings to stream")
    queries = load_queries(queries_path)
    if limit > 0:
        # a shortened run asks about its own classes and about the classes that no recording
        # of the whole split has (the absent-class check), not about the cut-off ones
        whole = {data.objects[int(data.object_id[data.recording_id == r][0])] for r in recs}
        recs = recs[:limit]
        mine = {data.objects[int(data.object_id[data.recording_id == r][0])] for r in recs}
        queries = {c: q for c, q in queries.items() if c in mine or c not in whole}
    stream = build_stream(data, recs, span=span)
    out = evaluate_stream(
        checkpoint,
        stream,
        queries,
        space=space,
        data_fingerprint=data.fingerprint(),
        groups=groups,
        pools=pools,
    )
    out["holdout"] = holdout
    out["span"] = span or STREAM_WINDOW
    out["stride"] = STREAM_STRIDE
    return out


def evaluate_stream(
    checkpoint: str | Path | None,
    stream: StreamSet,
    queries: dict[str, list[str]],
    *,
    space: Space | None = None,
    modes: Sequence[str] = MODES,
    workdir: str | Path | None = None,
    data_fingerprint: str | None = None,
    groups: Sequence[str | None] = (None,),
    pools: Sequence[str] = ("mean",),
) -> dict[str, Any]:
    """Score ``checkpoint`` (None: the shipped one) on ``stream`` with ``queries``; one real
    memory per mode in a temporary directory. Returns the metrics JSON (per mode).

    ``data_fingerprint`` (``StagData.fingerprint()`` of the files the stream was cut from)
    makes the leakage check decidable: ``leakage.status`` is ``overlap`` when the checkpoint
    was trained on these files without holding out the scored recordings."""
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.matching import MATCH_Z
    from tactus_memory.memory.main import Memory

    bad = template_collisions(queries)
    if bad:
        raise InvalidInputError(f"stream queries equal training templates: {bad}")
    for m in modes:
        if m not in MODES:
            raise InvalidInputError(f"unknown stream mode {m!r}; modes are {MODES}")
    for g in groups:
        if g not in GROUPS:
            raise InvalidInputError(f"unknown stream group {g!r}; groups are {GROUPS}")
    for p in pools:
        if p not in POOLS:
            raise InvalidInputError(f"unknown grasp pool {p!r}; pools are {POOLS}")
    enc = TactusEncoder(checkpoint)
    meta = enc.ckpt.meta
    out: dict[str, Any] = {
        "checkpoint": str(checkpoint) if checkpoint is not None else "default",
        "leakage": leakage(meta, sorted(stream.spans), data_fingerprint),
        "window": STREAM_WINDOW
        if stream.frames.shape[1] == STREAM_WINDOW
        else stream.frames.shape[1],
        "windows": len(stream),
        "idle_windows": int(stream.idle.sum()),
        "idle_fraction": float(stream.idle.mean()),
        "labelled_windows": int(stream.labelled.sum()),
        "labelled_windows_flagged_idle": int((stream.labelled & stream.idle).sum()),
        "recordings": sorted(stream.spans),
        "n_recordings": len(stream.spans),
        "n_queries": sum(len(v) for v in queries.values()),
    }
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for mode in modes:
            keep = ~stream.idle if mode == "served" else np.ones(len(stream), dtype=bool)
            if not keep.any():
                out[mode] = {"windows_stored": 0}
                continue
            mem = Memory.open(str(Path(tmp) / mode), space=space, background=False)
            try:
                mem.add_sense(enc)
                idx = np.flatnonzero(keep)
                ids = _store(mem, stream, idx)
                runs = [(g, p) for g in groups for p in (pools if g else ["mean"])]
                for g, pool in runs:
                    key = mode if g is None else f"{mode}_{g}"
                    key += "" if pool == "mean" else f"_{pool}"
                    bar = MATCH_Z["touch"]
                    out[key] = _score_mode(mem, stream, idx, ids, queries, bar, g, pool)
            finally:
                mem.close()
    return out
