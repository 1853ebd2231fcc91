"""Issue 36, defect 4: a re-embedding under a server already running on the store. After
``tactus reembed`` swaps the touch sense to another checkpoint, a memory (a server) opened
before the swap must never store a window embedded by the old checkpoint: its next write of
that sense is refused (SenseSwappedError, 409 ``sense-swapped``, nothing stored) and it
rebuilds the sense from the store's record, so the write sent again is embedded by the new
checkpoint. Real path: real LanceDB, real MiniLM, the shipped checkpoint and a second one
derived from it here (perturbed weights, ``save_checkpoint``), the real ``tactus reembed``
command and a real uvicorn."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from typer.testing import CliRunner

from benchmarks.serving import serve_app
from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.errors import SenseSwappedError
from tactus_memory.hashing import file_sha256
from tactus_memory.memory.main import Memory
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.touch.checkpoint import default_checkpoint_path, load_checkpoint
from tests.helpers.service import windows


@pytest.fixture(scope="module")
def second_checkpoint(tmp_path_factory) -> Path:
    """The shipped checkpoint with every float weight perturbed: another encoder of the
    same space, sensor and classes (another sha256)."""
    import torch

    from tactus_memory.touch.checkpoint import save_checkpoint

    ck = load_checkpoint(default_checkpoint_path())
    gen = torch.Generator().manual_seed(36)
    with torch.no_grad():
        for p in ck.model.parameters():
            p.add_(0.05 * p.abs().mean() * torch.randn(p.shape, generator=gen))
    path = tmp_path_factory.mktemp("ck") / "tactus-perturbed.safetensors"
    space_dim = int(ck.meta["space"]["dim"])
    save_checkpoint(path, ck.model, ck.targets, space_dim=space_dim,
                    calibration=ck.meta["calibration"])  # fmt: skip
    return path


@pytest.fixture(scope="module")
def encoders(second_checkpoint) -> tuple[TactusEncoder, TactusEncoder]:
    return TactusEncoder(), TactusEncoder(second_checkpoint)


def _stored_vector(memory: Memory, item_id: str) -> np.ndarray:
    return np.asarray(memory.get_item(item_id, vector=True).vector, dtype=np.float32)


def _reembed(path: Path, checkpoint: Path) -> dict:
    """``tactus reembed`` on the store: its own connection, as another process has."""
    from tactus_memory.cli import app

    args = ["reembed", "--data", str(path), "--sense", "touch", "--checkpoint", str(checkpoint)]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, (r.output, r.exception)
    return json.loads(r.stdout)  # the progress bar is on stderr


def _distances(vec: np.ndarray, window: np.ndarray, encoders) -> tuple[float, float]:
    old, new = (float(np.abs(vec - e.embed([e.validate(window)])[0]).max()) for e in encoders)
    return old, new


def test_a_memory_opened_before_a_reembed_never_stores_the_old_encoders_vectors(
    tmp_path, encoders, second_checkpoint, minilm_space
) -> None:
    old_enc, new_enc = encoders
    path = tmp_path / "mem"
    server = Memory.open(str(path), space=minilm_space, background=False)
    server.add_sense(old_enc)
    batch = windows(8, idle=set())
    first = server.add_many("glove", "touch", list(batch[:4]), t=[0.0, 1.0, 2.0, 3.0])
    old, new = _distances(_stored_vector(server, first[0]), batch[0], encoders)
    assert old < 1e-5 < 1e-3 < new  # the checkpoints differ enough to tell them apart

    report = _reembed(path, second_checkpoint)
    assert report["rows"] == 4
    assert report["provenance"]["checkpoint_sha256"] == file_sha256(second_checkpoint)

    with pytest.raises(SenseSwappedError, match=r"re-embedded to checkpoint") as err:
        server.add("glove", "touch", batch[4], t=4.0)
    assert file_sha256(second_checkpoint)[:12] in str(err.value)
    assert len(server) == 4  # nothing of the refused write was stored
    again = server.add("glove", "touch", batch[4], t=4.0)  # the sense followed the swap
    old, new = _distances(_stored_vector(server, again), batch[4], encoders)
    assert new < 1e-5 < old, (old, new)
    for item_id in first:  # the swapped rows are the new checkpoint's embedding of what is kept
        kept = server.get_item(item_id).raw
        vec = _stored_vector(server, item_id)
        old, new = (float(np.abs(vec - e.embed([kept])[0]).max()) for e in encoders)
        assert new < 1e-5 < old, (old, new)
    live = server.senses["touch"].provenance()["checkpoint_sha256"]
    assert live == file_sha256(second_checkpoint)


def test_a_running_server_refuses_then_embeds_with_the_new_checkpoint(
    tmp_path, encoders, second_checkpoint, minilm_space
) -> None:
    old_enc, _ = encoders
    path = tmp_path / "mem"
    memory = Memory.open(str(path), space=minilm_space)
    memory.add_sense(old_enc)
    batch = windows(6, idle=set())
    with serve_app(create_app(Settings(), memory=memory)) as base:
        body = {"windows": batch[:3].tolist(), "t": [0.0, 1.0, 2.0]}
        r = httpx.post(f"{base}/sessions/g/touch", json=body, timeout=120)
        assert r.status_code == 201, r.text

        _reembed(path, second_checkpoint)
        sha = file_sha256(second_checkpoint)

        one = {"frames": batch[3].tolist(), "t": 3.0}
        r = httpx.post(f"{base}/sessions/g/touch", json=one, timeout=120)
        assert r.status_code == 409, r.text
        assert r.json()["type"].endswith("sense-swapped") and sha[:12] in r.json()["detail"]
        r = httpx.post(f"{base}/sessions/g/touch", json=one, timeout=120)
        assert r.status_code == 201, r.text
        new_id = r.json()["ids"][0]
        listed = httpx.get(f"{base}/senses", timeout=60).json()["senses"]
        senses = {s["name"]: s for s in listed}
        assert senses["touch"]["provenance"]["checkpoint_sha256"] == sha
    old, new = _distances(_stored_vector(memory, new_id), batch[3], encoders)
    assert new < 1e-5 < old, (old, new)
    assert memory.session("g").counts["touch"] == 4


def test_a_restarted_server_never_brings_back_the_old_checkpoint(
    tmp_path, encoders, second_checkpoint, minilm_space
) -> None:
    """Issue 48, defect 5: after ``tactus reembed`` moved the store to checkpoint B, a server
    started again with the shipped checkpoint A re-registered A and stored A's vectors
    beside B's. Now naming A refuses the start with one line naming both checkpoints (and
    writes nothing), and a server naming none (the default ONNX server included) opens with
    the store's own B: its writes are B's embeddings."""
    from tactus_memory.service.app import register_default_senses
    from tactus_memory.service.startup import StartupError, explain

    path = tmp_path / "mem"
    memory = Memory.open(str(path), space=minilm_space)
    memory.add_sense(encoders[0])
    batch = windows(4, idle=set())
    memory.add_many("g", "touch", list(batch[:2]), t=[0.0, 1.0])
    _reembed(path, second_checkpoint)
    sha_a = file_sha256(default_checkpoint_path())
    sha_b = file_sha256(second_checkpoint)

    restarted = Memory.open(str(path), space=minilm_space)
    named_a = Settings(touch_checkpoint=str(default_checkpoint_path()))
    with pytest.raises(StartupError) as refused:
        register_default_senses(restarted, named_a)
    line = explain(refused.value, str(path))
    assert "\n" not in line and second_checkpoint.name in line
    assert default_checkpoint_path().name in line and sha_a[:12] in line and sha_b[:12] in line
    assert restarted.registry.stored_provenance("touch")["checkpoint_sha256"] == sha_b

    # none named, on the default ONNX server's settings: the store's own checkpoint
    again = Memory.open(str(path), space=minilm_space)
    assert register_default_senses(again, Settings(onnx=str(tmp_path / "no-onnx"))) is None
    assert again.senses["touch"].provenance()["checkpoint_sha256"] == sha_b
    with serve_app(create_app(Settings(), memory=again)) as base:
        one = {"frames": batch[2].tolist(), "t": 2.0}
        r = httpx.post(f"{base}/sessions/g/touch", json=one, timeout=120)
        assert r.status_code == 201, r.text
        listed = httpx.get(f"{base}/senses", timeout=60).json()["senses"]
    assert {s["name"]: s for s in listed}["touch"]["provenance"]["checkpoint_sha256"] == sha_b
    old, new = _distances(_stored_vector(again, r.json()["ids"][0]), batch[2], encoders)
    assert new < 1e-5 < old, (old, new)
