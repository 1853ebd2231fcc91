"""`tactus adapt` on objects the base never trained on, against teaching alone; and its time.

    python benchmarks/adapt.py --base runs/novel7/base.safetensors \
        [--out benchmarks/results/adapt.json]

**Novel-object split.** The base checkpoint is the demo recipe (MAE 150 x 128, then 60
supervised steps of batch 32, seed 0, ``--half``) trained on ``blindfolded_lite_train`` +
``weights_lite`` with EVERY recording of :data:`NOVEL` held out (``--holdout recordings@...``:
both blindfolded recordings and the weights recording of each; the command is in the JSON),
so neither its MAE nor its supervised training saw a frame of those 7 objects. The benchmark
checks that the checkpoint's recorded held-out recordings include every recording of them.

**Protocol** (a real memory: real LanceDB, real MiniLM). For each direction (lesson = the
lower-id blindfolded recording of each novel object, day = the other; then swapped):

* ``lesson`` session: the 7 lesson recordings laid end to end (the stream windowing; idle
  windows not stored); each is taught with ``memory.teach(<made-up label>)`` over its span
  (labels from ``teach_once.LABELS``, so the words give no help);
* ``day`` session: the 7 other recordings, and as distractors the higher-id recording of each
  of the 19 other objects (ones the base trained on);
* **teach**: ``"when was I holding the <label>?"`` over ``day`` (touch, k=20) with the base
  encoder: top-1 (first hit of the object's day recording), R@5, reciprocal rank (0 past 20);
* **adapt + teach**: ``tactus adapt``'s library call on what the memory was taught
  (``grasps_from_memory``: the stored windows of the taught spans; defaults of
  ``AdaptConfig``), ``memory.reembed("touch", adapted)``, the same questions;
* **adapt, untaught**: the teachings forgotten, the same questions (the adapted encoder's
  label targets alone).

Paired differences (adapt + teach minus teach) over the 14 (object, direction) units: mean
and 95 % t-interval, and how many units went up / down.

**Time.** ``tactus adapt --data FILE.npz --threads 2`` as a subprocess on 10 objects x 3
grasps: the 10 ``weights_lite`` recordings with the most labelled frames, each one's labelled
frames cut into 3 consecutive grasps (written at run time to a temporary .npz; no STAG slice is
kept), the shipped encoder as base; wall time of the command (imports, MiniLM, features,
steps, writing) and its CPU time (user + system, all threads), with the machine's load
average beside it (on a shared machine the wall time is mostly waiting for a core).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.teach_once import LABELS, QUESTION  # noqa: E402

#: the novel objects: every 4th of the 26 blindfolded objects with two recordings (sorted)
NOVEL = ("allen_key_set", "bracket", "clip", "gel", "multimeter", "screw_driver", "tape")
#: hits asked for (a reciprocal rank past this counts 0)
K = 20
TIMING_OBJECTS, TIMING_GRASPS = 10, 3
#: what adapt trains, each measured (``AdaptConfig.tune``)
TUNES = ("projector", "fusion")


def t_interval(x: list[float]) -> dict[str, float]:
    from scipy import stats

    a = np.asarray(x, float)
    m, se = float(a.mean()), float(a.std(ddof=1) / np.sqrt(len(a)))
    h = float(stats.t.ppf(0.975, len(a) - 1) * se) if se > 0 else 0.0
    return {"mean": m, "lo": m - h, "hi": m + h, "n": len(a)}


def ask(mem: Any, labels: dict[str, str], objects: list[str]) -> dict[str, dict[str, float]]:
    """Per object: top1, r5, rr of its label's question over ``day``."""
    out = {}
    for obj in objects:
        hits = mem.search(QUESTION.format(labels[obj]), k=K, senses=["touch"], session="day")
        got = [h.meta["object"] for h in hits]
        rank = got.index(obj) + 1 if obj in got else None
        out[obj] = {
            "top1": float(bool(got) and got[0] == obj),
            "r5": float(obj in got[:5]),
            "rr": 1.0 / rank if rank else 0.0,
        }
    return out


def add_stream(mem: Any, name: str, s: Any) -> None:
    keep = np.flatnonzero(~s.idle)
    mem.add_many(
        name, "touch", list(s.frames[keep]),
        t=s.t[keep].tolist(), t_end=s.t_end[keep].tolist(),
        meta=[{"object": s.obj[i]} for i in keep],
    )  # fmt: skip


def novel_split(base_path: Path, stag: Path) -> dict[str, Any]:
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace
    from tactus_memory.touch.checkpoint import heldout_recordings, load_checkpoint
    from tactus_memory.training import stream_eval
    from tactus_memory.training.adapt import AdaptConfig, adapt
    from tactus_memory.training.adapt_data import grasps_from_memory
    from tactus_memory.training.data import load_stag

    space = MiniLMSpace()  # loaded once, the memories' space
    data = load_stag(stag / "blindfolded_lite_train")
    base = load_checkpoint(base_path)
    held = set(heldout_recordings(base.meta))
    by_obj: dict[str, list[int]] = {}
    for r in np.unique(data.recording_id[data.valid]):
        o = data.objects[int(data.object_id[data.recording_id == r][0])]
        by_obj.setdefault(o, []).append(int(r))
    novel_recs = [data.recordings[r] for o in NOVEL for r in by_obj[o]]
    if not set(novel_recs) <= held:
        raise SystemExit(f"{base_path} trained on novel recordings {set(novel_recs) - held}")
    others = sorted(o for o, rs in by_obj.items() if len(rs) == 2 and o not in NOVEL)
    labels = dict(zip(NOVEL, LABELS, strict=False))
    units: list[dict[str, Any]] = []
    adapt_runs = []
    for direction in (0, 1):
        lesson_recs = [sorted(by_obj[o])[direction] for o in NOVEL]
        day_recs = [sorted(by_obj[o])[1 - direction] for o in NOVEL]
        day_recs += [sorted(by_obj[o])[1] for o in others]
        lesson = stream_eval.build_stream(data, lesson_recs)
        day = stream_eval.build_stream(data, day_recs)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "m"
            mem = Memory.open(str(path), space=space, background=False)
            mem.add_sense(TactusEncoder(base_path))
            add_stream(mem, "lesson", lesson)
            add_stream(mem, "day", day)
            for rec, (a, b) in lesson.spans.items():
                mem.teach(labels[lesson.rec_object[rec]], session="lesson", after=a, before=b)
            teach = ask(mem, labels, list(NOVEL))
            mem.close()
            grasps, _ = grasps_from_memory(path, base.model.cfg.frames, (32, 32), space=space)
            variants: dict[str, dict[str, Any]] = {}
            mem = Memory.open(str(path), space=space, background=False)
            for tune in TUNES:
                ck = Path(tmp) / f"{tune}.safetensors"
                started = time.perf_counter()
                summary = adapt(base, grasps, space, ck, AdaptConfig(tune=tune), progress=False)
                summary["wall_s"] = round(time.perf_counter() - started, 2)
                adapt_runs.append({"direction": direction, "tune": tune, **summary})
                mem.reembed("touch", TactusEncoder(ck))
                variants[f"adapt_{tune}_teach"] = ask(mem, labels, list(NOVEL))
                for label in labels.values():
                    mem.teachings.forget(label)
                variants[f"adapt_{tune}_untaught"] = ask(mem, labels, list(NOVEL))
                for rec, (a, b) in lesson.spans.items():
                    mem.teach(labels[lesson.rec_object[rec]], session="lesson", after=a, before=b)
            mem.close()
        for o in NOVEL:
            units.append({
                "object": o, "direction": direction, "label": labels[o],
                "lesson": data.recordings[sorted(by_obj[o])[direction]],
                "day": data.recordings[sorted(by_obj[o])[1 - direction]],
                "teach": teach[o], **{arm: v[o] for arm, v in variants.items()},
            })  # fmt: skip
        arms_here = [k for k, v in units[-1].items() if isinstance(v, dict)]
        print(direction, {k: np.mean([u[k]["top1"] for u in units]) for k in arms_here})
    arms = ["teach"] + [f"adapt_{t}_{w}" for t in TUNES for w in ("teach", "untaught")]
    metrics = ("top1", "r5", "rr")
    out: dict[str, Any] = {
        "novel_objects": list(NOVEL),
        "novel_recordings_held_out_of_base": sorted(novel_recs),
        "distractor_objects": others,
        "units": len(units),
        "arms": {a: {m: t_interval([u[a][m] for u in units]) for m in metrics} for a in arms},
        **{f"paired_{arm}_minus_teach": {} for arm in arms[1:]},
        "per_unit": units,
        "adapt_runs": adapt_runs,
    }
    for arm in arms[1:]:
        for m in metrics:
            d = [u[arm][m] - u["teach"][m] for u in units]
            row = t_interval(d)
            row.update(up=sum(x > 0 for x in d), down=sum(x < 0 for x in d))
            out[f"paired_{arm}_minus_teach"][m] = row
    return out


def timing(stag: Path) -> dict[str, Any]:
    from tactus_memory.training.data import load_stag

    data = load_stag(stag / "weights_lite")
    recs = np.unique(data.recording_id[data.valid])
    counts = {int(r): int((data.valid & (data.recording_id == r)).sum()) for r in recs}
    chosen = sorted(counts, key=lambda r: (-counts[r], r))[:TIMING_OBJECTS]
    pressure, label, recording = [], [], []
    for r in chosen:
        idx = np.flatnonzero(data.valid & (data.recording_id == r))
        idx = idx[np.argsort(data.ts[idx], kind="stable")]
        obj = data.objects[int(data.object_id[idx[0]])]
        for g, part in enumerate(np.array_split(idx, TIMING_GRASPS)):
            pressure.append(data.pressure[part])
            label += [obj] * len(part)
            recording += [f"{data.recordings[r]}-{g + 1}"] * len(part)
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "grasps.npz"
        np.savez(npz, pressure=np.concatenate(pressure), label=np.array(label),
                 recording=np.array(recording))  # fmt: skip
        out = Path(tmp) / "runs" / "adapted.safetensors"
        cli = "import sys; from tactus_memory.cli import main; sys.argv[0] = 'tactus'; main()"
        cmd = [sys.executable, "-c", cli, "adapt", "--data", str(npz), "--out", str(out)]
        cmd += ["--threads", "2"]
        load_before = os.getloadavg()
        cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True, check=True)
        wall = time.perf_counter() - started
        cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = sum(getattr(cpu_after, f) - getattr(cpu_before, f) for f in ("ru_utime", "ru_stime"))
        summary = json.loads(done.stdout)
    return {
        "command": "tactus adapt --data grasps.npz --out runs/adapted.safetensors --threads 2",
        "objects": TIMING_OBJECTS,
        "grasps_per_object": TIMING_GRASPS,
        "frames": len(label),
        "windows": summary["grasps"]["windows"],
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "feature_s": summary["feature_s"],
        "train_s": summary["train_s"],
        "steps": summary["steps"],
        "own_windows_top1": summary["own_windows_top1"],
        "loadavg_1m_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "cpus": os.cpu_count(),
        "nice": os.nice(0),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--base", required=True, help="the novel-object base checkpoint")
    ap.add_argument("--base-command", default="", help="how the base was trained (recorded)")
    ap.add_argument("--stag", help="STAG folder (default: the data home's stag/)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/adapt.json"))
    ap.add_argument(
        "--skip-timing", action="store_true", help="keep the timing of the --out file there"
    )
    ap.add_argument(
        "--only-timing", action="store_true", help="rerun the timing into the --out file"
    )
    args = ap.parse_args()
    if args.only_timing:
        from tactus_memory.datasets.home import data_home

        kept = json.loads(Path(args.out).read_text())
        kept["timing_10x3"] = timing(Path(args.stag) if args.stag else data_home().stag)
        Path(args.out).write_text(json.dumps(kept, indent=1) + "\n")
        print(json.dumps(kept["timing_10x3"], indent=1))
        return
    from tactus_memory.datasets.home import data_home
    from tactus_memory.touch.checkpoint import read_metadata

    stag = Path(args.stag) if args.stag else data_home().stag
    meta = read_metadata(args.base)
    from tactus_memory.hashing import file_sha256

    result: dict[str, Any] = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/adapt.py --base runs/novel7/base.safetensors",
        "base": {
            "file": Path(args.base).name,
            "sha256": file_sha256(Path(args.base)),
            "trained_with": args.base_command,
            "train_args": {k: meta["train_args"].get(k) for k in ("steps", "batch", "lr", "seed")},
            "pretrained": meta["metrics"].get("pretrained"),
        },
        "question": QUESTION,
        "k": K,
    }
    started = time.perf_counter()
    result["novel"] = novel_split(Path(args.base), stag)
    result["novel"]["wall_s"] = round(time.perf_counter() - started, 1)
    if not args.skip_timing:
        result["timing_10x3"] = timing(stag)
    elif Path(args.out).is_file():
        result["timing_10x3"] = json.loads(Path(args.out).read_text()).get("timing_10x3")
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    keys = [k for k in result["novel"] if k.startswith(("arms", "paired"))]
    print(json.dumps({k: result["novel"][k] for k in keys}, indent=1))
    print(json.dumps(result.get("timing_10x3"), indent=1))


if __name__ == "__main__":
    main()
