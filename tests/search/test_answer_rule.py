"""Which occurrence answers last/first/count (search.matching.ANSWER_KEEP) on the real path
(real MiniLM, real LanceDB, real uvicorn), and scores that stop moving once a sense's
calibration is final (search.scoring.FINAL_ROWS)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from benchmarks.answer_rule import NOTES  # the mug at 10 s; later notes pass its bar too
from tactus_memory.errors import InvalidInputError
from tactus_memory.matching import answering
from tactus_memory.memory.main import Memory
from tactus_memory.results import Moment
from tactus_memory.search.scoring import FINAL_ROWS
from tests.helpers.fakes import HashingSpace

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def notes(tmp_path_factory, minilm_space) -> Memory:
    mem = Memory.open(str(tmp_path_factory.mktemp("answer") / "mem"), space=minilm_space)
    for text, t in NOTES:
        mem.add("notes", "text", text, t=t)
    return mem


def test_last_is_the_note_that_says_it_not_the_latest_near_miss(notes: Memory) -> None:
    every = notes.occurrences("picked up the mug", session="notes", answer=0.0)
    # near misses written later pass the match bar too ...
    assert every.passed == every.count >= 3
    assert every.moments[-1].t > 10.0
    # ... but only the note that says it matches about as well as the best one
    occ = notes.occurrences("picked up the mug", session="notes")
    assert occ.answer is None and occ.passed == every.passed
    assert occ.count == 1 and occ.moments[0].t == 10.0
    assert notes.last("picked up the mug", session="notes").t == 10.0
    assert notes.first("picked up the mug", session="notes").t == 10.0
    assert notes.count("picked up the mug", session="notes") == 1
    # a question with one clear answer is unchanged by the rule
    assert notes.last("picked up the screwdriver", session="notes").t == 100.0


def test_answer_rule_over_http(notes: Memory) -> None:
    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    with TestClient(create_app(Settings(), memory=notes)) as c:
        q = {"q": "picked up the mug", "session": "notes"}
        body = c.get("/count", params=q).json()
        assert body["count"] == 1 and body["passed"] >= 3 and body["answer"] is None
        assert c.get("/last", params=q).json()["moment"]["t"] == 10.0
        late = c.get("/last", params={**q, "answer": 0}).json()["moment"]["t"]
        assert late > 10.0
        assert c.get("/count", params={**q, "answer": 1.5}).status_code == 422


def _moment(t: float, score: float, sense: str = "text") -> Moment:
    return Moment(session="s", t=t, t_end=t + 1, score=score, senses=[sense], best="x", hits=[])


def test_answering_cuts_at_the_first_clear_break() -> None:
    # repeats that match alike all answer; a clear best answers alone
    alike = [_moment(10, 6.5), _moment(40, 5.8), _moment(70, 4.9)]
    assert [m.t for m in answering(alike, 0.75)] == [10, 40, 70]
    clear = [_moment(10, 8.0), _moment(40, 5.5), _moment(70, 4.3), _moment(130, 4.2)]
    assert [m.t for m in answering(clear, 0.75)] == [10]
    # the break is taken where it first occurs, best first: 8 -> 7.5 -> 4 cuts below 7.5
    two = [_moment(10, 4.0), _moment(40, 7.5), _moment(70, 8.0)]
    assert [m.t for m in answering(two, 0.75)] == [40, 70]
    assert answering(clear, 0.0) == clear and answering([], 0.75) == []
    # per sense: a note far above two grasps does not silence them
    mixed = [_moment(10, 8.5), _moment(20, 6.0, "touch"), _moment(30, 5.2, "touch")]
    assert [m.t for m in answering(mixed, 0.75)] == [10, 20, 30]
    # the defaults: text cut at 0.75, touch not cut (its repeats vary too much)
    touch = [_moment(10, 7.3, "touch"), _moment(40, 6.7, "touch"), _moment(70, 3.4, "touch")]
    assert [m.t for m in answering(touch)] == [10, 40, 70]
    assert [m.t for m in answering(clear)] == [10]
    with pytest.raises(InvalidInputError, match="answer"):
        answering(clear, -0.1)


def _notes(mem: Memory, n: int, start: float, word: str) -> None:
    texts = [f"{word} entry number {i} about the {word} of the day" for i in range(n)]
    mem.add_many("log", "text", texts, t=[start + i for i in range(n)])


def test_scores_stop_moving_once_the_calibration_is_final(tmp_path) -> None:
    young = Memory.open(str(tmp_path / "young"), space=HashingSpace(dim=64), background=False)
    young.add("log", "text", "the blue mug on the shelf", t=0.0)
    _notes(young, 99, 1.0, "weather")
    before = young.search("blue mug", k=1)[0].score
    _notes(young, 104, 500.0, "garden")  # unrelated notes: the row count doubles
    after = young.search("blue mug", k=1)[0].score
    info = {s.name: s for s in young.sense_info()}["text"]
    assert before != after and not info.calib_final  # a young sense is still learning
    old = Memory.open(str(tmp_path / "old"), space=HashingSpace(dim=64), background=False)
    old.add("log", "text", "the blue mug on the shelf", t=0.0)
    _notes(old, FINAL_ROWS, 1.0, "weather")
    before = old.search("blue mug", k=1)[0].score
    info = {s.name: s for s in old.sense_info()}["text"]
    assert info.calib_final and info.calib_n >= FINAL_ROWS
    _notes(old, 2 * FINAL_ROWS, 10_000.0, "garden")  # more than doubles it again
    assert old.search("blue mug", k=1)[0].score == before
