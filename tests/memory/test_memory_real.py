"""Memory on the real path: real MiniLM (session fixture) + real LanceDB files in tmp_path."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import (
    DimensionMismatchError,
    InvalidIdError,
    InvalidInputError,
    SpaceMismatchError,
    UnknownSenseError,
)
from tactus_memory.memory.main import Memory
from tests.helpers.fakes import HashingSpace

pytestmark = pytest.mark.slow

NOTES = [
    "put the red mug on the top shelf",
    "the operator opened the fridge door",
    "wiped the kitchen table with a wet sponge",
    "picked up a tennis ball from the floor",
    "the robot charged its battery overnight",
    "folded a blue towel and placed it in the basket",
    "poured water from the kettle into a glass",
    "tightened a screw with the screwdriver",
    "watered the plant by the window",
    "stacked three wooden blocks into a tower",
]


@pytest.fixture
def real_mem(tmp_path, minilm_space) -> Memory:
    mem = Memory.open(str(tmp_path / "mem"), space=minilm_space)
    mem.add_many("s1", "text", NOTES, t=[float(i) for i in range(len(NOTES))])
    mem.add_many("s2", "text", NOTES[:5], t=[100.0 + i for i in range(5)])
    return mem


def test_matching_note_ranks_first(real_mem: Memory) -> None:
    hits = real_mem.search("where did I leave the coffee cup?", k=3, session="s1")
    assert hits[0].text == NOTES[0]
    assert hits[0].score > hits[1].score
    hits = real_mem.search("cleaning a surface", k=1, session="s1")
    assert hits[0].text == NOTES[2]


def test_real_filters_never_leak(real_mem: Memory) -> None:
    hits = real_mem.search("mug", k=50, session="s2")
    assert len(hits) == 5 and {h.session for h in hits} == {"s2"}
    hits = real_mem.search("mug", k=50, after=2.5, before=5.0)
    assert sorted(h.t for h in hits) == [3.0, 4.0, 5.0]
    assert real_mem.search("mug", k=5, session="s3") == []


def test_real_reopen_delete_and_mismatch(tmp_path, minilm_space) -> None:
    path = str(tmp_path / "mem")
    mem = Memory.open(path, space=minilm_space)
    ids = mem.add_many("s1", "text", NOTES, t=list(range(10)))
    mem.add_many("s2", "text", NOTES[:3])
    del mem
    again = Memory.open(path, space=minilm_space)
    assert len(again) == 13
    assert again.search("a ball on the ground", k=1, session="s1")[0].id == ids[3]
    assert again.delete([ids[3]]) == 1
    assert ids[3] not in {h.id for h in again.search("a ball on the ground", k=5)}
    assert again.delete_session("s2") == 3
    assert [s.id for s in again.sessions()] == ["s1"] and len(again) == 9
    with pytest.raises(SpaceMismatchError, match="minilm-l6.*fake-hash"):
        Memory.open(path, space=HashingSpace(dim=384))


def test_real_hostile_inputs(real_mem: Memory) -> None:
    with pytest.raises(InvalidIdError):
        real_mem.search("mug", session="s1' OR 1=1 --")
    with pytest.raises(InvalidIdError):
        real_mem.add('x"; drop', "text", "hello")
    with pytest.raises(UnknownSenseError):
        real_mem.search("mug", senses=["smell"])
    assert len(real_mem) == 15


def test_real_vector_sense_round_trip(real_mem: Memory, minilm_space) -> None:
    real_mem.add_sense(VectorSense("motion", dim=384))
    # motion vectors from "an external encoder": here MiniLM embeddings of motion captions
    captions = ["arm lifts quickly upward", "robot walks forward slowly", "gripper rotates left"]
    vecs = minilm_space.embed_texts(captions)
    ids = real_mem.add_many("s1", "motion", list(vecs), t=[1.0, 2.0, 3.0])
    hit = real_mem.search_like("motion", vecs[1], k=1)[0]
    assert hit.id == ids[1] and hit.sense == "motion"
    hits = real_mem.search("walking ahead", k=1, senses=["motion"])
    assert hits[0].id == ids[1]
    with pytest.raises(DimensionMismatchError):
        real_mem.add("s1", "motion", np.ones(128))
    bad = vecs[0].copy()
    bad[5] = np.nan
    with pytest.raises(InvalidInputError):
        real_mem.add("s1", "motion", bad)
    assert real_mem.session("s1").counts == {"motion": 3, "text": 10}


def test_real_cli_search(tmp_path, minilm_space, monkeypatch) -> None:
    import json

    from typer.testing import CliRunner

    import tactus_memory.spaces as spaces
    from tactus_memory.cli import app

    monkeypatch.setattr(spaces, "get_space", lambda name="minilm", path=None: minilm_space)
    Memory.open(str(tmp_path / "m"), space=minilm_space).add_many("s1", "text", NOTES)
    res = CliRunner().invoke(
        app, ["search", "watering flowers", "--data", str(tmp_path / "m"), "--k", "1", "--json"]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)[0]["text"] == NOTES[8]
