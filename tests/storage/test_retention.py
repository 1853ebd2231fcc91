"""Retention (issue 25): expiry per tenant, session or sense, stale-duplicate thinning, their
configuration in the one settings object, on real LanceDB stores (MiniLM for the real path)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from tactus_memory.adapters.text import TextSense
from tactus_memory.cli import app as cli
from tactus_memory.memory.main import Memory
from tactus_memory.policies import THIN_COSINE, RetentionRule
from tactus_memory.settings import Settings
from tactus_memory.storage.retention import DAY_S, resolve, thin_run_drops

ROOT = Path(__file__).resolve().parents[2]


def unit(v: np.ndarray) -> np.ndarray:
    return (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)


# ------------------------------------------------------------------ policy
def test_the_most_specific_rule_wins_field_by_field() -> None:
    cfg = Settings(
        retain_days=30,
        thin_after_days=2,
        retention=[
            {"tenant": "lab", "retain_days": 7},
            {"sense": "touch", "retain_days": 3, "thin_cosine": 0.9},
            {"session": "demo-*", "retain_days": None},  # demos are kept forever
            {"session": "demo-keep", "retain_days": 1},
        ],
    ).maintenance()
    assert resolve(cfg, None, "s1", "text").retain_days == 30  # no rule: store-wide
    assert resolve(cfg, "lab", "s1", "text").retain_days == 7
    lab_touch = resolve(cfg, "lab", "s1", "touch")
    assert (lab_touch.retain_days, lab_touch.thin_cosine) == (3, 0.9)  # sense over tenant
    assert lab_touch.thin_after_days == 2  # no rule sets it: store-wide
    assert resolve(cfg, "lab", "demo-1", "touch").retain_days is None  # session prefix
    assert resolve(cfg, None, "demo-keep", "touch").retain_days == 1  # exact id over prefix
    assert resolve(cfg, None, "s1", "text").thin_cosine == THIN_COSINE


def test_rules_are_checked_where_they_are_read(tmp_path, monkeypatch) -> None:
    for bad in ({"session": "a b"}, {"sense": "Touch"}, {"tenant": "x/y"}, {"retain_days": 0},
                {"thin_cosine": 1.5}, {"sesion": "s1"}):  # fmt: skip
        with pytest.raises(ValidationError):
            RetentionRule(**bad)
    # the environment (JSON) and the TOML file give the same rules, as every setting
    monkeypatch.setenv("TACTUS_RETENTION", json.dumps([{"sense": "touch", "retain_days": 5}]))
    monkeypatch.setenv("TACTUS_THIN_AFTER_DAYS", "1.5")
    cfg = Settings().maintenance()
    assert cfg.thin_after_days == 1.5 and resolve(cfg, None, "s", "touch").retain_days == 5
    monkeypatch.delenv("TACTUS_RETENTION")
    monkeypatch.delenv("TACTUS_THIN_AFTER_DAYS")
    toml = tmp_path / "tactus.toml"
    toml.write_text(
        'retain_days = 90\n[[retention]]\nsession = "lab-*"\nretain_days = 7\n'
        '[[retention]]\nsession = "demo-*"\nretain_days = "none"\n'  # TOML has no null
    )
    cfg = Settings(config=str(toml)).maintenance()
    assert resolve(cfg, None, "lab-3", "text").retain_days == 7
    assert resolve(cfg, None, "demo-3", "text").retain_days is None
    assert resolve(cfg, None, "home", "text").retain_days == 90


def test_thinning_keeps_the_first_and_last_of_each_run() -> None:
    rng = np.random.default_rng(0)
    a, b = unit(rng.standard_normal((2, 32)))
    near = lambda v, e: unit(v + e * rng.standard_normal(32))  # noqa: E731
    rows = [a, near(a, 0.01), near(a, 0.01), near(a, 0.01), b, near(b, 0.01), a, b]
    drops = thin_run_drops(np.stack(rows), 0.98)
    # run a,a',a'',a''' keeps its first and last; b,b' has nothing between; singles stay
    assert drops.tolist() == [False, True, True, False, False, False, False, False]
    assert not thin_run_drops(np.stack(rows), 1.0).any()  # nothing is that close
    assert thin_run_drops(np.zeros((0, 32), np.float32), 0.9).shape == (0,)


# ------------------------------------------------------------------ on a real store
NOTE = "robot parked at the charging dock"
LEFT = "robot left the charging dock and drove to the kitchen"


@pytest.fixture
def real(tmp_path, minilm_space):
    def open_(**settings) -> Memory:
        cfg = Settings(**settings).maintenance()
        # maintenance inline: no background pass outlives the test
        return Memory.open(
            str(tmp_path / "mem"), space=minilm_space, maintenance=cfg, background=False
        )

    return open_


def test_expiry_per_session_and_sense_on_a_real_store(real) -> None:
    mem = real(retain_days=30, retention=[{"session": "keep-*", "retain_days": None},
                                          {"sense": "note", "retain_days": 2}])  # fmt: skip
    mem.add_sense(TextSense(mem.space, name="note"))  # a second text sense
    mem.add_many("s1", "text", ["put the red mug on the shelf", "opened the fridge"])
    mem.add_many("s1", "note", ["battery at 80 percent"])
    mem.add_many("keep-lab", "text", ["calibrated the glove"])
    now = time.time()
    rep = mem.store.retention.run(now + 3 * DAY_S, force=True)  # day 3: the note expires
    assert rep.expired == 1 and {(s.id, s.n) for s in mem.sessions()} == {
        ("s1", 2),
        ("keep-lab", 1),
    }
    rep = mem.store.retention.run(now + 31 * DAY_S, force=True)  # day 31: s1's text too
    assert rep.expired == 2 and [s.id for s in mem.sessions()] == ["keep-lab"]
    assert rep.expired_total == 3
    assert mem.search("glove calibration", k=1)[0].text == "calibrated the glove"


def test_thinning_drops_stale_duplicates_of_real_minilm_text(real) -> None:
    mem = real(thin_after_days=1)
    log = [NOTE] * 6 + [LEFT] + [NOTE] * 3
    mem.add_many("robot", "text", log, t=[float(i) for i in range(len(log))])
    mem.add_many("robot", "text", [NOTE] * 3, t=[20.0, 21.0, 22.0], source="cam2")
    mem.add_many("other", "text", [NOTE] * 3, t=[0.0, 1.0, 2.0])
    now = time.time()
    assert mem.store.retention.run(now, force=True).thinned == 0  # nothing is a day old yet
    rep = mem.store.retention.run(now + 2 * DAY_S, force=True)
    kept = sorted(_items(mem, "robot", ""))
    # two runs of NOTE keep their first and last; the change in between is kept
    assert kept == [(0.0, NOTE), (5.0, NOTE), (6.0, LEFT), (7.0, NOTE), (9.0, NOTE)]
    assert len(_items(mem, "robot", "cam2")) == 2 and len(_items(mem, "other", "")) == 2
    assert rep.thinned == 5 + 1 + 1 and rep.groups_thinned == 3
    # a later pass has nothing new to look at, and thinning twice removes nothing more
    assert mem.store.retention.run(now + 3 * DAY_S, force=True).thinned == 0


def test_tactus_maintain_applies_retention(tmp_path, minilm_space, monkeypatch) -> None:
    path = tmp_path / "mem"
    mem = Memory.open(str(path), space=minilm_space, background=False)
    mem.add_many("old-1", "text", ["first note", "second note"])
    mem.add_many("fresh", "text", ["third note"])
    time.sleep(1.0)  # the notes are now more than 1e-5 days (0.86 s) old
    monkeypatch.setenv("TACTUS_RETENTION", json.dumps([{"session": "old-*", "retain_days": 1e-5}]))
    res = CliRunner().invoke(cli, ["maintain", "--data", str(path), "--once", "--retain", "0"])
    assert res.exit_code == 0, res.output
    line = next(json.loads(x) for x in res.stdout.splitlines() if '"retention"' in x)
    assert line["retention"]["expired"] == 2
    after = Memory.open(str(path), space=minilm_space, background=False)
    assert [s.id for s in after.sessions()] == ["fresh"]


def _items(mem: Memory, session: str, source: str) -> list[tuple[float, str]]:
    rows = mem.store.scan(f"session = '{session}' AND source = '{source}'", ["t", "text"])
    return [(r["t"], r["text"]) for r in rows.to_pylist()]


def test_thinning_a_real_glove_recording(tmp_path, minilm_space, stag_dir) -> None:
    """A STAG recording streamed as the service windows it, thinned at the measured bar:
    each dropped window lies inside a run (its nearest kept window before it is within the
    bar of it and of the nearest kept one after), and the ends of the session are kept."""
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.touch.windows import cut_windows
    from tactus_memory.training.stag_io import read_mat_fields

    fields = read_mat_fields(stag_dir / "weights_lite" / "metadata.mat")
    rec = np.asarray(fields["recordingId"]).reshape(-1)
    idx = np.flatnonzero(rec == rec[0])  # the first recording (~16 s of grasps at 7.4 Hz)
    pressure, ts = np.asarray(fields["pressure"])[idx], np.asarray(fields["ts"]).reshape(-1)[idx]
    settings = Settings(thin_after_days=1)
    w = cut_windows(pressure, ts, window=settings.window, stride=settings.stride)
    w = w.take(~w.idle)  # (Wn, K, 32, 32) raw int16, as the touch sense stores them
    cfg = settings.maintenance()
    mem = Memory.open(str(tmp_path / "mem"), space=minilm_space, maintenance=cfg, background=False)
    mem.add_sense(TactusEncoder())
    ids = mem.add_many("glove", "touch", list(w.frames), t=list(w.t), t_end=list(w.t_end))
    vectors = {i: np.asarray(mem.get_item(i, vector=True).vector) for i in ids}
    rep = mem.store.retention.run(time.time() + 2 * DAY_S, force=True)
    kept = set(mem.store.scan(None, ["id"]).column("id").to_pylist())
    assert rep.thinned == len(ids) - len(kept) > 0  # a hand held still repeats itself
    assert ids[0] in kept and ids[-1] in kept
    for j, i in enumerate(ids):
        if i in kept:
            continue
        anchor = next(ids[a] for a in range(j - 1, -1, -1) if ids[a] in kept)
        last = next(ids[b] for b in range(j + 1, len(ids)) if ids[b] in kept)
        assert vectors[anchor] @ vectors[i] >= THIN_COSINE - 1e-6
        assert vectors[anchor] @ vectors[last] >= THIN_COSINE - 1e-6
