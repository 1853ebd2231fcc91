"""Recording ingest throughput: a 10-minute 30 Hz glove recording with notes, MCAP or ROS 2 bag.

    nice python benchmarks/recordings.py [--minutes 10] [--hz 30] [--format mcap|bag]
                                         [--out benchmarks/results/recordings.json]

Writes a real recording (tests/helpers/recording_files.py: synthetic raw glove frames as ``mono16``
Images on ``/glove/pressure``, a ``std_msgs/String`` note every 10 s on ``/notes``, and an
unmapped ``/imu`` topic at 30 Hz), then ingests it into a fresh real store with the real
MiniLM space and the shipped TactusEncoder (K = 8, stride 8), and times:

* ``read``: reading and decoding the mapped topics only (no embedding, no writes);
* ``ingest``: the whole ``Memory.ingest_recording`` (read, window, validate, embed, commit;
  both models loaded before);
* ``reingest``: the same file again (every id already present: nothing embedded or added).

messages/s counts messages read on the mapped topics; rows/s counts stored rows (touch
windows + notes). The machine is shared: the load average is recorded with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactus_memory.recordings import samples as rf  # noqa: E402
from tactus_memory.recordings.ingest import ingest_recording  # noqa: E402
from tactus_memory.recordings.reader import open_recording  # noqa: E402

NOTE_EVERY_S = 10.0
TOPICS = {"/notes": "text", "/glove/pressure": "touch"}
START_NS = 1_750_000_000 * rf.NS


def make_messages(minutes: float, hz: float, seed: int = 7) -> list[rf.Msg]:
    n = int(round(minutes * 60 * hz))
    frames = rf.synthetic_grasp(n, seed=seed)  # (n, 32, 32) int16 raw
    msgs = rf.glove("/glove/pressure", frames, start_ns=START_NS, hz=hz)
    n_notes = int(minutes * 60 / NOTE_EVERY_S)
    msgs += [
        rf.note("/notes", START_NS + round(i * NOTE_EVERY_S * rf.NS), f"note {i}: grasp the mug")
        for i in range(n_notes)
    ]
    msgs += [rf.vector3("/imu", START_NS + round(i * rf.NS / hz)) for i in range(n)]
    return msgs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--hz", type=float, default=rf.GLOVE_HZ)
    ap.add_argument("--format", choices=["mcap", "bag"], default="mcap")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/recordings.json"))
    args = ap.parse_args()

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace

    work = Path(tempfile.mkdtemp(prefix="tactus-bench-rec-"))
    try:
        t = time.perf_counter()
        msgs = make_messages(args.minutes, args.hz)
        if args.format == "mcap":
            path = rf.write_mcap(work / "glove.mcap", msgs)
            size = path.stat().st_size
        else:
            path = rf.write_bag(work / "glove_bag", msgs, storage="sqlite3")
            size = sum(p.stat().st_size for p in path.iterdir())
        write_s = time.perf_counter() - t
        mapped = sum(1 for m in msgs if m.topic in TOPICS)

        rec = open_recording(path)
        t = time.perf_counter()
        read = sum(1 for _ in rec.messages(list(TOPICS)))
        read_s = time.perf_counter() - t
        assert read == mapped, (read, mapped)

        memory = Memory.open(str(work / "mem"), space=MiniLMSpace(), background=False)
        encoder = TactusEncoder()
        memory.add_sense(encoder)
        # load both models before timing (MiniLM loads lazily on its first text)
        memory.space.embed_texts(["warm up"])
        encoder.embed(np.full((1, 8, 32, 32), 600, np.int16))
        load_before = os.getloadavg()
        t0_ingest = time.perf_counter()
        s = ingest_recording(memory, path, session="bench", topics=TOPICS)
        t_ingest = time.perf_counter() - t0_ingest
        again = ingest_recording(memory, path, session="bench", topics=TOPICS)
        load_after = os.getloadavg()
        rows = sum(s.rows.values())
        result = {
            "recording": {
                "format": args.format,
                "minutes": args.minutes,
                "hz": args.hz,
                "messages": len(msgs),
                "mapped_messages": mapped,
                "bytes": size,
                "write_s": round(write_s, 2),
            },
            "read": {"seconds": round(read_s, 2), "messages_per_s": round(read / read_s, 1)},
            "ingest": {
                "seconds": round(s.seconds, 2),
                "wall_s": round(t_ingest, 2),
                "messages": s.messages,
                "rows": s.rows,
                "messages_per_s": round(s.messages_per_s, 1),
                "rows_per_s": round(s.rows_per_s, 1),
                "realtime_factor": round(args.minutes * 60 / s.seconds, 2),
            },
            "reingest": {
                "seconds": round(again.seconds, 2),
                "rows_added": sum(again.rows.values()),
                "existing": again.existing,
                "messages_per_s": round(again.messages_per_s, 1),
            },
            "rows_total": rows,
            "machine": {
                "cpus": os.cpu_count(),
                "loadavg_before": [round(x, 2) for x in load_before],
                "loadavg_after": [round(x, 2) for x in load_after],
                "python": platform.python_version(),
                "note": "shared machine: other processes compete for the cores",
            },
        }
        assert again.rows == {}, again.rows
    finally:
        shutil.rmtree(work, ignore_errors=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
