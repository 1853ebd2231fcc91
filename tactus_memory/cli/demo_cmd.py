"""``tactus demo``: touch answering a question, for a newcomer, in one command.

With the STAG files present (``tactus data fetch stag``, or ``--from DIR``), three glove
recordings are laid end to end as one session, cut as the stream cuts them, and stored with a
few notes in a memory (a temporary folder, or ``--data``). The touch sense is the shipped DEMO
checkpoint (:data:`~tactus_memory.touch.checkpoint.DEMO_CHECKPOINT`), trained with ``--holdout
one-per-object@blindfolded``; the three recordings are taken from the held-out recordings its
metadata names, so the demo asks only about recordings it never trained on (a test checks
this). Then five questions whose right answers the demo knows are asked (three about touch, two
about the notes), each printed with its best hit, score, match and whether it was right: right
means the top hit is the right span (or note) AND a match. The demo ends with the checkpoint's
measured held-out figures (:data:`HELDOUT_FIGURES`), so three answers are read against them.
Without the files it says in one line how to get them and runs the notes part.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.space_opts import fail

#: the session the demo writes
SESSION = "demo-glove"
#: the STAG subset the held-out recordings come from
SUBSET = "blindfolded_lite_train"
#: the demo checkpoint's measured held-out figures (tuple top-1, stream R@1/R@5 with 95 %
#: intervals), written by ``benchmarks/touch_demo.py`` (also in benchmarks/results/touch_demo.json)
HELDOUT_FIGURES = Path(__file__).parents[1] / "touch" / "checkpoints" / "demo-heldout.json"
#: (object, the question asked about it): the objects whose held-out recordings are stored
TOUCH_QUESTIONS = (
    ("mug", "when was I holding a mug?"),
    ("scissors", "when was I holding the scissors?"),
    ("full_can", "grabbing an unopened can"),
)
#: what "right" means in the demo's count
RIGHT = "right: the top hit is the answer and a match"
#: (t, note) written to the session; the note questions below know which is right
NOTES = (
    (1.0, "the operator said the charger is in the left drawer"),
    (5.0, "battery at 40 percent, heading back to the dock"),
)
NOTE_QUESTIONS = (
    ("where is the charger?", 0),
    ("how much battery was left?", 1),
)


@dataclass
class Question:
    """One question, and the span (touch) or note text the right answer has."""

    text: str
    sense: str
    right_span: tuple[float, float] | None = None
    right_text: str | None = None

    def judge(self, hit: Any) -> bool:
        """Right: the hit is the right span (touch) or note (text), and a match."""
        if not hit.match:
            return False
        if self.right_span is not None:
            lo, hi = self.right_span
            return hit.t <= hi and hit.t_end >= lo
        return hit.text == self.right_text


def demo_recordings(data: Any, meta: dict[str, Any]) -> dict[str, int]:
    """object -> the id (in ``data``) of a recording of it that the checkpoint of ``meta`` was
    trained without (its recorded held-out recordings), for TOUCH_QUESTIONS' objects."""
    from tactus_memory.touch.checkpoint import heldout_recordings

    held = set(heldout_recordings(meta))
    out: dict[str, int] = {}
    for r, name in enumerate(data.recordings):
        m = data.recording_id == r
        if name not in held or not (m & data.valid).any():
            continue
        out.setdefault(data.objects[int(data.object_id[m][0])], r)
    return {obj: out[obj] for obj, _ in TOUCH_QUESTIONS if obj in out}


def touch_session(stag: Path, memory: Any, start: float, meta: dict[str, Any]) -> list[Question]:
    """Store the held-out recordings (of the checkpoint of ``meta``) of TOUCH_QUESTIONS'
    objects from ``start`` (s); the touch questions, each knowing its recording's span."""
    from tactus_memory.training.data import load_stag  # no torch: make run installs none
    from tactus_memory.training.stream_eval import build_stream

    data = load_stag(stag / SUBSET)
    recs = list(demo_recordings(data, meta).values())
    if not recs:
        raise ValueError(f"none of the demo checkpoint's held-out recordings is in {stag}")
    stream = build_stream(data, recs)
    t, t_end = stream.t + start, stream.t_end + start
    memory.add_many(
        SESSION,
        "touch",
        list(stream.frames),
        t=[float(x) for x in t],
        t_end=[float(x) for x in t_end],
        source="glove",
    )  # idle windows (no contact) are skipped, as the stream skips them
    spans = {stream.rec_object[name]: span for name, span in stream.spans.items()}
    return [
        Question(q, "touch", right_span=(spans[obj][0] + start, spans[obj][1] + start))
        for obj, q in TOUCH_QUESTIONS
        if obj in spans
    ]


def heldout_line() -> str:
    """The demo checkpoint's measured held-out figures, one line."""
    f = json.loads(HELDOUT_FIGURES.read_text())

    def fig(name: str) -> str:
        m = f[name]
        return f"{m['value']:.2f} [{m['lo']:.2f}, {m['hi']:.2f}]"

    return (
        f"measured on its {f['recordings']} held-out recordings: tuple top-1 {fig('tuple_top1')}, "
        f"stream R@1 {fig('stream_r1')}, R@5 {fig('stream_r5')} (95 % intervals)"
    )


def ask(memory: Any, question: Question) -> str:
    """One line: the question, its best hit (when, score, match and bar) and whether right."""
    hits = memory.search(question.text, 1, senses=[question.sense])
    if not hits:
        return f"{question.text!r}: no {question.sense} hit  right: no"
    h = hits[0]
    what = f"{h.sense} {h.t:.1f}-{h.t_end:.1f} s" + (f" {h.text!r}" if h.text else "")
    match = "yes" if h.match else "no"
    right = "yes" if question.judge(h) else "no"
    bar = "" if h.bar is None else f" (bar {h.bar:.2f})"
    return f"{question.text!r}: hit {what}  score {h.score:.2f}  match {match}{bar}  right: {right}"


@app.command()
def demo(
    data: Annotated[
        str | None,
        typer.Option(help="Store the demo session here (default: a temporary folder)."),
    ] = None,
    stag_from: Annotated[
        str | None,
        typer.Option("--from", help="The STAG folder (default: `tactus data path --stag`)."),
    ] = None,
) -> None:
    """Touch answering questions: a short glove session from held-out STAG recordings and a
    few notes, then five questions whose right answers are known (hit, score, match, right)."""
    from tactus_memory.datasets.home import data_home
    from tactus_memory.memory.main import Memory
    from tactus_memory.senses.plugins import create_sense
    from tactus_memory.touch.checkpoint import demo_checkpoint_path

    stag = Path(stag_from).expanduser() if stag_from else data_home().stag
    have_stag = (stag / SUBSET / "metadata.mat").is_file()
    tmp = None
    if data is None:
        tmp = tempfile.TemporaryDirectory(prefix="tactus-demo-")
        data = tmp.name
    try:
        memory = Memory.open(data)
        for t, note in NOTES:
            memory.add(SESSION, "text", note, t=t)
        questions = [Question(q, "text", right_text=NOTES[i][1]) for q, i in NOTE_QUESTIONS]
        if have_stag:
            sense = create_sense("touch", memory.space, checkpoint=demo_checkpoint_path())
            memory.add_sense(sense)
            typer.echo(
                f"storing glove recordings from {stag / SUBSET} that the demo touch model "
                f"({sense.ckpt.path.name}) never trained on ..."
            )
            questions = touch_session(stag, memory, 10.0, sense.ckpt.meta) + questions
        else:
            typer.echo(
                f"no STAG files at {stag}: `tactus data fetch stag` gets them (or --from DIR); "
                "asking about the notes only"
            )
        counts = sorted(memory.session(SESSION).counts.items())
        typer.echo(f"session {SESSION!r}: " + ", ".join(f"{n} {sense}" for sense, n in counts))
        right = 0
        for question in questions:
            line = ask(memory, question)
            right += line.endswith("right: yes")
            typer.echo(line)
        typer.echo(
            f"{right} of {len(questions)} right (right: the top hit is the answer and a match)"
        )
        if have_stag:
            typer.echo(f"the demo touch model, {heldout_line()}")
    except Exception as exc:  # noqa: BLE001  (one line, exit 2)
        fail(f"the demo failed: {type(exc).__name__}: {exc}")
    finally:
        if tmp is not None:
            tmp.cleanup()
