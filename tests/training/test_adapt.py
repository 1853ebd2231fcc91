"""``tactus adapt`` (issue 46): a few labelled grasps fine-tune a checkpoint's projector.

A tiny base checkpoint (random ``tactus-tiny`` weights, targets of three other classes in the
real MiniLM space) is adapted on ``examples/make_grasps.py``'s synthetic .npz (3 objects x 3
grasps, glove frames): through the CLI into a folder that does not exist yet, then resumed
to more steps; the adapted encoder must rank each object's own windows above the others for
the plain question about it, better than the base did. "Train on what I taught": the grasps
are read back from a real memory's taught spans."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.cli import app
from tests.helpers.training import _last_json, _run

ROOT = Path(__file__).resolve().parents[2]
#: the base's own classes (none of them is an object of the grasps file)
BASE_CLASSES = ["mug", "pen", "ball"]


@pytest.fixture(scope="module")
def base(tmp_path_factory, minilm_space) -> Path:
    import torch

    from tactus_memory.touch.checkpoint import save_checkpoint
    from tactus_memory.touch.model import create_model
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.targets import build_targets

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("base") / "tiny.safetensors"
    model = create_model("tactus-tiny", out_dim=minilm_space.dim)
    targets = build_targets(minilm_space, BASE_CLASSES)
    save_checkpoint(
        path, model, targets, space_dim=minilm_space.dim, calibration=STAG_GLOVE.to_dict()
    )
    return path


@pytest.fixture(scope="module")
def grasps_npz(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("grasps") / "grasps.npz"
    runpy.run_path(str(ROOT / "examples/make_grasps.py"))["main"](str(path))
    return path


def question_precision(checkpoint: Path, npz: Path, space) -> float:
    """For each object of the file, "a hand holding a <object>" through the checkpoint's
    query transform against every window of the file: the share of its own windows among
    the first n (n = its window count), averaged over the objects."""
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.training.adapt_data import grasps_from_data
    from tactus_memory.training.npz_io import load_npz

    enc = TactusEncoder(checkpoint)
    g = grasps_from_data(load_npz(npz), enc.profile, enc.frames, npz.name)
    z = enc.embed(g.windows, calibrated=True)  # (W, D)
    labels = np.array(g.labels)
    out = []
    for obj in g.classes:
        q = enc.ckpt.targets.query_transform(space.embed_texts([f"a hand holding a {obj}"]))
        top = np.argsort(-(z @ q.reshape(-1)))[: int((labels == obj).sum())]
        out.append(float((labels[top] == obj).mean()))
    return float(np.mean(out))


def test_adapt_into_a_new_folder_resumes_and_ranks_the_taught_objects_better(
    base, grasps_npz, tmp_path, minilm_space, monkeypatch
) -> None:
    # the command's space is the real MiniLM: the one this session loaded, not a second copy
    monkeypatch.setattr("tactus_memory.cli.adapt_cmd.resolve_or_exit", lambda *a: minilm_space)
    out = tmp_path / "runs" / "new" / "adapted.safetensors"
    assert not out.parent.exists()
    args = ["adapt", "--data", str(grasps_npz), "--base", str(base), "--out", str(out)]
    args += ["--copies", "2", "--threads", "1"]
    first = _last_json(_run([*args, "--steps", "20"]))
    assert out.is_file() and (out.parent / "adapted.safetensors.resume.pt").is_file()
    assert first["steps"] == 20 and first["steps_this_run"] == 20
    assert first["new_labels"] == ["sponge", "drill", "ladle"]
    assert first["grasps"]["grasps"] == 9
    again = _last_json(_run([*args, "--steps", "60", "--resume"]))
    assert again["steps"] == 60 and again["steps_this_run"] == 40  # went on from step 20

    from tactus_memory.touch.checkpoint import read_metadata

    meta = read_metadata(out)
    assert meta["classes"] == [*BASE_CLASSES, "sponge", "drill", "ladle"]
    assert meta["metrics"]["adapt"]["base"]["file"] == base.name
    before = question_precision(base, grasps_npz, minilm_space)
    after = question_precision(out, grasps_npz, minilm_space)
    assert after > before and after >= 0.9, (before, after)


def test_adapt_trains_on_what_a_memory_was_taught(base, grasps_npz, tmp_path, minilm_space):
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.touch.checkpoint import load_checkpoint
    from tactus_memory.training.adapt import AdaptConfig, adapt
    from tactus_memory.training.adapt_data import grasps_from_memory
    from tactus_memory.training.npz_io import load_npz

    data = load_npz(grasps_npz)
    path = tmp_path / "memory"
    mem = Memory.open(str(path), space=minilm_space, background=False)
    mem.add_sense(TactusEncoder(base))
    t = data.ts
    spans, windows, t0, t1 = {}, [], [], []
    for r, name in enumerate(data.recordings):  # one window of 8 raw frames every 4 frames
        idx = np.flatnonzero(data.recording_id == r)
        starts = range(idx[0], idx[-1] - 7, 4)
        windows += [data.pressure[s : s + 8] for s in starts]
        t0 += [float(t[s]) for s in starts]
        t1 += [float(t[s + 7]) for s in starts]
        spans[name] = (float(t[idx[0]]), float(t[idx[-1]]))
    mem.add_many("bench", "touch", windows, t=t0, t_end=t1)  # one commit
    taught = ["sponge-1", "drill-1", "ladle-1"]  # the first grasp of each object only
    for name in taught:
        mem.teach(name.split("-")[0], session="bench", after=spans[name][0], before=spans[name][1])
    mem.close()
    grasps, space = grasps_from_memory(path, 8, (32, 32), space=minilm_space)
    assert grasps.classes == ["sponge", "drill", "ladle"] and grasps.source == str(path)
    assert len(np.unique(grasps.grasp)) == 3
    assert len(grasps.windows) == 12  # the 4 stored windows of each of the 3 taught grasps
    out = tmp_path / "a" / "taught.safetensors"
    cfg = AdaptConfig(steps=60, copies=2, lr=1e-2)
    s = adapt(load_checkpoint(base), grasps, space, out, cfg, progress=False)
    assert s["own_windows_top1"]["after"] > s["own_windows_top1"]["before"]
    assert out.is_file()


def test_adapt_errors_are_one_line(base, tmp_path) -> None:
    out = tmp_path / "x" / "a.safetensors"
    r = CliRunner().invoke(app, ["adapt", "--data", str(tmp_path / "nope.npz"), "--out", str(out)])
    assert r.exit_code == 2 and "no such file or folder" in r.output and "nope.npz" in r.output
    empty = tmp_path / "empty"
    (empty / "items.lance").mkdir(parents=True)  # looks like a memory, holds nothing taught
    r = CliRunner().invoke(
        app, ["adapt", "--data", str(empty), "--base", str(base), "--out", str(out)]
    )
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and str(empty) in r.output, r.output
    assert not out.exists()
