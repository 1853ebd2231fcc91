"""Questions an agent would ask, answered through the MCP tools (NaVQA-style, no LLM).

    nice python benchmarks/agent_questions.py [--out benchmarks/results/agent_questions.json]

A scripted 4-minute kitchen shift is written as a real MCAP recording
(tests/helpers/recording_files.py:
narration as ``std_msgs/String`` on ``/notes``, the glove as 30 Hz ``mono16`` frames on
``/glove/pressure``: a pressed blob while a thing is handled, the resting pedestal between),
ingested into a fresh real store (real MiniLM, the shipped TactusEncoder; idle windows are not
stored), and served by ``tactus mcp`` over stdio. A deterministic driver (one tool call per
question, a fixed rule from the answer to yes/no, a time or a number) asks:

* ``when_last`` / ``when_first``: "when did I last/first <do X>?" -> ``last`` / ``first``;
  right when the moment starts within ``WHEN_TOLERANCE_S`` of the true note time;
* ``count``: "how many times did I <do X>?" -> ``count``; right when exact;
* ``yes_no``: "did I <do X> after T?" (and things that never happened) -> ``count`` with
  ``after`` -> yes when count > 0;
* ``order``: "what did I do just before/after <a one-off>?" -> ``before`` / ``after`` with
  text senses -> the nearest note's text;
* ``touch_contact``: "was I touching something at T?" -> ``timeline`` of touch over [T, T].

Questions use paraphrases ("grab the red cup" for the note "picked up the red mug"). Each
question of the when/count/yes-no types is asked twice: with ``senses=["text"]`` (what the
notes say) and with every sense (touch windows join the evidence). Ground truth comes from the
script; the accuracy per type (and strategy) goes to the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactus_memory.recordings import samples as rf  # noqa: E402
from tactus_memory.recordings.ingest import ingest_recording  # noqa: E402

SESSION = "shift"
HZ = 30.0
SHIFT_S = 240.0
#: a thing is handled from GRASP_BEFORE s before its note to GRASP_AFTER s after it
GRASP_BEFORE, GRASP_AFTER = 2.0, 3.0
#: a "when" answer is right when it starts this close to the true note time (the grasp
#: windows of the same moment start GRASP_BEFORE s earlier)
WHEN_TOLERANCE_S = 5.0
START_NS = 1_750_000_000 * rf.NS

#: kind -> (what the narration says, how the question says it)
KINDS = {
    "mug": ("picked up the red mug", "grab the red cup"),
    "sink": ("put the mug in the sink", "place the cup into the sink"),
    "wipe": ("wiped the table with a sponge", "clean the table"),
    "fridge": ("opened the fridge door", "open the refrigerator"),
    "milk": ("poured milk into a glass", "pour some milk"),
    "drawer": ("closed the cutlery drawer", "shut the drawer"),
    "phone": ("answered the phone", "take a phone call"),
}
#: (note time s, kind), the shift's script
SCRIPT = [
    (12.0, "mug"), (30.0, "sink"), (45.0, "wipe"), (60.0, "fridge"), (70.0, "milk"),
    (85.0, "mug"), (100.0, "drawer"), (115.0, "fridge"), (130.0, "wipe"), (150.0, "mug"),
    (170.0, "phone"), (185.0, "milk"), (200.0, "drawer"), (215.0, "wipe"), (230.0, "fridge"),
]  # fmt: skip
OPENING = (0.0, "started the kitchen shift")
#: things that never happened (yes/no questions whose answer is no)
NEVER = ["spill the coffee", "water the plants", "take out the trash", "feed the cat"]
#: times (s) probed by the touch-contact questions
CONTACT_PROBES = [5.0, 11.0, 20.0, 31.0, 52.0, 61.0, 92.0, 101.0, 140.0, 171.0, 222.0, 231.0]


@dataclass
class Question:
    kind: str  # the question type
    text: str
    tool: str
    args: dict[str, Any]
    truth: Any
    strategy: str = "-"


def occurrences(kind: str) -> list[float]:
    return [t for t, k in SCRIPT if k == kind]


def grasping(t: float) -> bool:
    return any(n - GRASP_BEFORE <= t <= n + GRASP_AFTER for n, _ in SCRIPT)


def questions() -> list[Question]:
    """The question set, with its ground truth computed from the script."""
    qs: list[Question] = []
    for strategy, senses in (("text", ["text"]), ("all_senses", None)):
        scope = {"session": SESSION, **({"senses": senses} if senses else {})}
        for kind, (_, ask) in KINDS.items():
            times = occurrences(kind)
            qs.append(Question("when_last", f"When did I last {ask}?", "last",
                               {"query": ask, **scope}, times[-1], strategy))  # fmt: skip
            qs.append(Question("when_first", f"When did I first {ask}?", "first",
                               {"query": ask, **scope}, times[0], strategy))  # fmt: skip
            qs.append(Question("count", f"How many times did I {ask}?", "count",
                               {"query": ask, **scope}, len(times), strategy))  # fmt: skip
            after_last = times[-1] + GRASP_AFTER + 2.0
            before_last = times[-1] - 1.0 - GRASP_BEFORE
            for t in (before_last, after_last):
                qs.append(Question("yes_no", f"Did I {ask} after {t:g} s?", "count",
                                   {"query": ask, "after": t, **scope},
                                   t <= times[-1], strategy))  # fmt: skip
        for ask in NEVER:
            qs.append(Question("yes_no", f"Did I {ask}?", "count", {"query": ask, **scope},
                               False, strategy))  # fmt: skip
    notes = [OPENING, *((t, KINDS[k][0]) for t, k in SCRIPT)]
    for kind in ("sink", "phone"):  # the one-off events: the anchor is unambiguous
        (t,) = occurrences(kind)
        i = [n for n, _ in notes].index(t)
        ask = KINDS[kind][1]
        args = {"anchor": ask, "window": 30.0, "session": SESSION, "senses": ["text"],
                "anchor_senses": ["text"]}  # fmt: skip
        qs.append(Question("order", f"What did I do just before I {ask}?", "before", args,
                           notes[i - 1][1]))  # fmt: skip
        qs.append(Question("order", f"What did I do just after I {ask}?", "after", args,
                           notes[i + 1][1]))  # fmt: skip
    for t in CONTACT_PROBES:
        qs.append(Question("touch_contact", f"Was I touching something at {t:g} s?", "timeline",
                           {"session": SESSION, "senses": ["touch"], "after": t, "before": t,
                            "limit": 5}, grasping(t)))  # fmt: skip
    return qs


def judge(q: Question, answer: dict[str, Any]) -> tuple[Any, bool]:
    """The driver's rule: a tool's answer -> (the answer to the question, whether right)."""
    if q.kind in ("when_last", "when_first"):
        got = answer["moment"]["t"] if answer["found"] else None
        return got, got is not None and abs(got - q.truth) <= WHEN_TOLERANCE_S
    if q.kind == "count":
        return answer["count"], answer["count"] == q.truth
    if q.kind == "yes_no":
        return answer["count"] > 0, (answer["count"] > 0) == q.truth
    if q.kind == "order":
        items = answer["items"]
        if not items:
            return None, False
        nearest = items[-1] if q.tool == "before" else items[0]
        return nearest.get("text"), nearest.get("text") == q.truth
    if q.kind == "touch_contact":
        items = answer["items"]
        touching = any(i.get("touch", {}).get("contact_taxels", 0) > 0 for i in items)
        return touching, touching == q.truth
    raise ValueError(q.kind)


def recording(path: Path) -> Path:
    """The shift as a real MCAP file: notes on /notes, the glove on /glove/pressure."""
    n = int(SHIFT_S * HZ)
    rng = np.random.default_rng(0)
    frames = (512 + rng.normal(0, 2, (n, 32, 32))).clip(500, 1000).astype(np.int16)
    blob = rf.synthetic_grasp(n, seed=1)
    for i in range(n):
        if grasping(i / HZ):
            frames[i] = blob[i]
    msgs = rf.glove("/glove/pressure", frames, start_ns=START_NS, hz=HZ)
    notes = [OPENING, *((t, KINDS[k][0]) for t, k in SCRIPT)]
    msgs += [rf.note("/notes", START_NS + round(t * rf.NS), text) for t, text in notes]
    return rf.write_mcap(path, msgs)


async def ask_all(data: Path, qs: list[Question]) -> list[dict[str, Any]]:
    """Every question through ``tactus mcp`` over stdio (the SDK's client)."""
    from mcp import Client, StdioServerParameters

    params = StdioServerParameters(
        command=sys.executable,
        args=["-c", "from tactus_memory.cli import main; main()", "mcp", "--data", str(data)],
        env={"OMP_NUM_THREADS": "1"},
    )
    out = []
    async with Client(params, read_timeout_seconds=120) as client:
        sessions = json.loads((await client.call_tool("sessions", {})).content[0].text)
        t0 = sessions["sessions"][0]["t_min"]  # the shift's clock starts at its first item
        assert abs(t0) < 1e-6, t0  # relative times: the recording's clock (ingest default)
        for q in qs:
            start = time.perf_counter()
            r = await client.call_tool(q.tool, q.args)
            ms = (time.perf_counter() - start) * 1e3
            if r.is_error:
                got, right = f"tool error: {r.content[0].text}", False
            else:
                got, right = judge(q, json.loads(r.content[0].text))
            out.append({"type": q.kind, "strategy": q.strategy, "question": q.text,
                        "tool": q.tool, "truth": q.truth, "answer": got, "right": right,
                        "ms": round(ms, 1)})  # fmt: skip
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    groups: dict[str, list[bool]] = defaultdict(list)
    for r in rows:
        key = r["type"] if r["strategy"] == "-" else f"{r['type']}/{r['strategy']}"
        groups[key].append(r["right"])
    return {
        k: {"n": len(v), "right": sum(v), "accuracy": round(sum(v) / len(v), 3)}
        for k, v in sorted(groups.items())
    }


def main() -> None:
    import anyio

    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/agent_questions.json"))
    args = ap.parse_args()

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory

    work = Path(tempfile.mkdtemp(prefix="tactus-bench-agent-"))
    wall = time.perf_counter()
    try:
        path = recording(work / "shift.mcap")
        with Memory.open(str(work / "memory"), background=False) as memory:
            memory.add_sense(TactusEncoder())
            topics = {"/notes": "text", "/glove/pressure": "touch"}
            ingest = ingest_recording(memory, path, session=SESSION, topics=topics)
        qs = questions()
        rows = anyio.run(ask_all, work / "memory", qs)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result = {
        "what": "scripted questions over a recorded 4-minute kitchen shift (MCAP), answered "
        "through `tactus mcp` tools over stdio by a deterministic driver (no LLM)",
        "accuracy": summarise(rows),
        "overall": {
            "n": len(rows),
            "accuracy": round(sum(r["right"] for r in rows) / len(rows), 3),
        },
        "tool_ms_median": round(statistics.median(r["ms"] for r in rows), 1),
        "recording": {
            "seconds": SHIFT_S,
            "hz": HZ,
            "notes": len(SCRIPT) + 1,
            "rows": ingest.rows,
            "skipped": ingest.skipped,
        },
        "when_tolerance_s": WHEN_TOLERANCE_S,
        "wall_s": round(time.perf_counter() - wall, 1),
        "machine": {
            "cpus": os.cpu_count(),
            "loadavg": [round(x, 2) for x in os.getloadavg()],
            "python": platform.python_version(),
        },
        "questions": rows,
    }
    out = Path(args.out)
    out.write_text(json.dumps(result, indent=2, default=str) + "\n")
    print(json.dumps({k: result[k] for k in ("accuracy", "overall", "wall_s")}, indent=2))


if __name__ == "__main__":
    main()
