"""How often a text match is right at the text bar (issue 46: "a match that means a precision").

    python benchmarks/text_precision.py [--out benchmarks/results/text_precision.json]

The question set: ``benchmarks/text_questions.json``, 40 notes each with a question asking for
it in other words. A real memory (real MiniLM, real LanceDB) holds two sessions: "A" with the
even-numbered notes among :data:`DISTRACTORS` robot-log notes (``benchmarks/text_notes.py``,
seed 5), "B" with the odd-numbered ones among as many others (seed 6). Each of the 40
questions is asked of both sessions (80 questions): in one its note is there (right: the top
text hit is that note), in the other it is not (any match is wrong). The text sense's
calibration is the store's own, final (more than ``scoring.FINAL_ROWS`` rows): the scores a
grown memory gives. The same again with :data:`YOUNG` robot-log notes per session (a young
memory: the shipped prior blended in, ``benchmarks/text_prior.py``).

For each memory, the rule of ``tactus_memory/training/bar_rule.py``: precision at each bar of
the sweep with its 95 % Wilson interval, the lowest bar whose lower bound reaches the target,
and the precision at the shipped text bar (``matching.MATCH_Z["text"]``). Writes ``--out`` and
the grown memory's row to ``tactus_memory/spaces/match-precision.json`` (``GET /senses``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.text_notes import notes  # noqa: E402

QUESTIONS = ROOT / "benchmarks/text_questions.json"
#: robot-log notes per session: a grown memory (calibration final) and a young one
DISTRACTORS = 1100
YOUNG = 100
#: the distractor seeds of sessions A and B
SEEDS = {"A": 5, "B": 6}


def measure(space: Any, per_session: int) -> dict[str, Any]:
    from tactus_memory.matching import MATCH_Z
    from tactus_memory.memory.main import Memory
    from tactus_memory.training.bar_rule import choose_bar

    pairs = json.loads(QUESTIONS.read_text())["pairs"]
    held = {"A": [p for i, p in enumerate(pairs) if i % 2 == 0], "B": pairs[1::2]}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        mem = Memory.open(str(Path(tmp) / "m"), space=space, background=False)
        for s, own in held.items():
            mem.add_many(s, "text", [n for n, _ in own] + notes(per_session, SEEDS[s]))
        calib = mem.calibration("text")
        for s, own in held.items():
            present = {n for n, _ in own}
            for note, q in pairs:
                h = mem.search(q, k=1, senses=["text"], session=s)[0]
                rows.append(
                    {
                        "question": q,
                        "session": s,
                        "note_present": note in present,
                        "top": h.text,
                        "score": h.score,
                        "right": note in present and h.text == note,
                    }
                )
        mem.close()
    chosen = choose_bar([r["score"] for r in rows], [r["right"] for r in rows], MATCH_Z["text"])
    present = [r for r in rows if r["note_present"]]
    bar = MATCH_Z["text"]
    return {
        "notes_per_session": per_session + len(held["A"]),
        "calibration": {"mu": calib.mu, "sigma": calib.sigma, "n": calib.n, "final": calib.final},
        **chosen,
        "recall_at_shipped_bar": sum(r["right"] and r["score"] >= bar for r in present)
        / len(present),
        "absent_matched_at_shipped_bar": sum(
            r["score"] >= bar for r in rows if not r["note_present"]
        ),
        "rows": rows,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/text_precision.json")
    args = ap.parse_args()
    from tactus_memory.spaces.figures import MATCH_PRECISION, figures_path
    from tactus_memory.spaces.minilm import MiniLMSpace
    from tactus_memory.training.bar_rule import senses_row

    space = MiniLMSpace()
    grown = measure(space, DISTRACTORS)
    young = measure(space, YOUNG)
    for name, m in (("grown", grown), ("young", young)):
        print(name, m["calibration"], m["at_shipped_bar"], "bar at target", m["bar_at_target"])
    questions = (
        "benchmarks/text_questions.json: 40 paraphrase questions, each asked of a session "
        f"holding its note and of one without it (80), among {DISTRACTORS} robot-log notes "
        "per session (top text hit)"
    )
    row = senses_row(grown, questions, "a grown memory (calibration final), real MiniLM")
    doc = {
        "source": "benchmarks/text_precision.py",
        "precision_at_bar": {space.name: {"text": row}},
    }
    figures_path(MATCH_PRECISION).write_text(json.dumps(doc, indent=1) + "\n")
    out = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/text_precision.py",
        "senses_row": row,
        "grown": grown,
        "young": young,
    }
    args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
