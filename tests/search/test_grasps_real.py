"""Grasps on the real path (issue 22): real MiniLM, real LanceDB, a real tactus-tiny
checkpoint (tests/helpers/touch_pair.py) as the touch sense, windows cut from synthetic STAG
recordings by the stream windowing and laid end to end as one session
(``touch/training/stream_eval.build_stream``); plus ``tactus eval --stream --group grasp``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.memory.main import Memory
from tactus_memory.results import Grasp
from tactus_memory.training import stream_eval
from tactus_memory.training.data import load_stag
from tests.helpers.touch_pair import Pair, train_pair

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> Pair:
    return train_pair(tmp_path_factory.mktemp("pair"))


@pytest.fixture(scope="module")
def stream(pair):
    data = load_stag(pair.stag[0])
    return stream_eval.build_stream(data, list(range(len(data.recordings))))


def test_grasps_never_cross_recordings_and_pool_their_windows(tmp_path, pair, stream, minilm_space):
    mem = Memory.open(str(tmp_path / "m"), space=minilm_space, background=False)
    enc = TactusEncoder(pair.a)
    mem.add_sense(enc)
    keep = np.flatnonzero(~stream.idle)
    ids = mem.add_many("day", "touch", list(stream.frames[keep]),
                       t=stream.t[keep].tolist(), t_end=stream.t_end[keep].tolist())  # fmt: skip
    rec_of = {i: stream.recording[j] for i, j in zip(ids, keep, strict=True)}
    grasps = mem.search("a hand holding a pen", k=100, senses=["touch"], group="grasp")
    assert grasps and all(isinstance(g, Grasp) for g in grasps)
    seen: set[str] = set()
    for g in grasps:
        recs = {rec_of[i] for i in g.ids}
        assert len(recs) == 1  # 10 s between recordings: a grasp never spans two
        a, b = stream.spans[recs.pop()]
        assert a <= g.t <= g.t_end <= b + 1e-6
        assert not seen & set(g.ids)  # one hit per grasp: no window in two grasps
        seen |= set(g.ids)
        vecs = np.stack([mem.get_item(i, vector=True).vector for i in g.ids])
        pooled = vecs.mean(axis=0) / np.linalg.norm(vecs.mean(axis=0))
        q = enc.query_transform(minilm_space.embed_texts(["a hand holding a pen"], query=True))
        assert g.cosine == pytest.approx(float(pooled @ q[0]), abs=1e-4)
    assert len(grasps) < len(seen)  # grouping happened: fewer grasps than windows
    scores = [g.score for g in grasps]
    assert scores == sorted(scores, reverse=True)


def test_stream_eval_scores_windows_and_grasps(pair, stream, minilm_space) -> None:
    present = set(stream.rec_object.values())
    queries = {c: q for c, q in stream_eval.load_queries().items() if c in present}
    out = stream_eval.evaluate_stream(
        pair.a, stream, queries, space=minilm_space, modes=("served",), groups=(None, "grasp"),
        pools=("mean", "max"),
    )  # fmt: skip
    w, g, gmax = out["served"], out["served_grasp"], out["served_grasp_max"]
    assert w["group"] is None and g["group"] == gmax["group"] == "grasp"
    assert g["pool"] == "mean" and gmax["pool"] == "max"
    assert w["queries_scored"] == g["queries_scored"] == sum(len(q) for q in queries.values())
    # a grasp scored by its best window ranks first exactly when that window does, and the
    # right object's grasp is never behind its first window's rank
    assert gmax["r@1"] == pytest.approx(w["r@1"]) and gmax["r@5"] >= w["r@5"]
    for m in (w, g, gmax):
        for key in ("r@1", "r@5", "mrr", "last_correct", "count_exact"):
            assert 0.0 <= m[key] <= 1.0
        assert m["r@1"] <= m["r@5"]
    assert "served_grasp" in stream_eval.stream_markdown(out)


def test_cli_eval_stream_group_grasp(pair, tmp_path) -> None:
    from tactus_memory.cli import app

    js = tmp_path / "eval.json"
    args = ["eval", "--checkpoint", str(pair.a), "--data", str(pair.stag[0])]
    args += ["--holdout", "one-per-object@blindfolded", "--no-analysis", "--votes", "1"]
    grasp = ["--stream", "--group", "grasp", "--grasp-pool", "mean", "--grasp-pool", "top"]
    r = CliRunner().invoke(app, [*args, *grasp, "--json", str(js)])
    assert r.exit_code == 0, (r.output, r.exception)
    stream = json.loads(js.read_text())["stream"]
    assert stream["served_grasp"]["group"] == "grasp" and stream["served"]["group"] is None
    assert stream["served_grasp_top"]["pool"] == "top"
    assert "by grasp (mean)" in r.output and "by grasp (top)" in r.output
    r = CliRunner().invoke(app, [*args, "--group", "grasp", "--json", str(js)])
    assert r.exit_code == 2  # --group needs --stream
