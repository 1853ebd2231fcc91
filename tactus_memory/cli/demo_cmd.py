"""``tactus demo``: touch answering a question, for a newcomer, in one command.

With the STAG files present (``tactus data fetch stag``, or ``--from DIR``), three held-out
glove recordings (one per object, none seen in the shipped model's training: the
``one-per-object@blindfolded`` split) are laid end to end as one session, cut as the stream
cuts them, and stored with a few notes in a memory (a temporary folder, or ``--data``). Then
five questions whose right answers the demo knows are asked (three about touch, two about the
notes), each printed with its best hit, score, match and whether it was right. Without the
files it says in one line how to get them and runs the notes part.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.space_opts import fail

#: the session the demo writes
SESSION = "demo-glove"
#: the STAG subset the held-out recordings come from, and the split that names them
SUBSET = "blindfolded_lite_train"
HOLDOUT = "one-per-object@blindfolded"
#: (object, the question asked about it): the objects whose held-out recordings are stored
TOUCH_QUESTIONS = (
    ("mug", "when was I holding a mug?"),
    ("scissors", "when was I holding the scissors?"),
    ("full_can", "grabbing an unopened can"),
)
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
        if self.right_span is not None:
            lo, hi = self.right_span
            return hit.t <= hi and hit.t_end >= lo
        return hit.text == self.right_text


def touch_session(stag: Path, memory: Any, start: float) -> list[Question]:
    """Store the held-out recordings of TOUCH_QUESTIONS' objects from ``start`` (s); the touch
    questions, each knowing its recording's span."""
    from tactus_memory.training.stream_eval import build_stream
    from tactus_memory.training.train import holdout_recordings, load_data

    data = load_data([stag / SUBSET])
    by_object = {
        data.objects[int(data.object_id[data.recording_id == r][0])]: r
        for r in holdout_recordings(data, HOLDOUT)
    }
    recs = [by_object[obj] for obj, _ in TOUCH_QUESTIONS if obj in by_object]
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
            memory.add_sense(create_sense("touch", memory.space))
            typer.echo(f"storing held-out glove recordings from {stag / SUBSET} ...")
            questions = touch_session(stag, memory, start=10.0) + questions
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
        typer.echo(f"{right} of {len(questions)} right")
    except Exception as exc:  # noqa: BLE001  (one line, exit 2)
        fail(f"the demo failed: {type(exc).__name__}: {exc}")
    finally:
        if tmp is not None:
            tmp.cleanup()
