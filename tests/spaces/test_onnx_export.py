"""The ONNX exports of both serving encoders (tactus_memory.export.onnx, run by
tactus_memory.spaces.onnx_runtime on ONNX Runtime) give the torch models' vectors: the bundled
MiniLM
through the model's own tokenizer, and the shipped touch encoder; `tactus serve --onnx` serves
both without loading torch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

pytest.importorskip("onnxruntime", reason="the [onnx] extra is not installed")

from benchmarks.serving import free_port, start_serve, stop_process  # noqa: E402
from tactus_memory.adapters.touch import TactusEncoder  # noqa: E402
from tactus_memory.errors import InvalidInputError  # noqa: E402
from tactus_memory.export.onnx import export_minilm, export_touch  # noqa: E402
from tactus_memory.spaces.minilm import MiniLMSpace  # noqa: E402
from tactus_memory.spaces.onnx_runtime import MINILM_MAX_TOKENS, OnnxMiniLM, OnnxTouch  # noqa: E402
from tests.helpers.servers import touch_and_note_found  # noqa: E402

TEXTS = [
    "where did I put the red mug?",
    "x",
    "squeezing a tennis ball gently with two fingers on the kitchen table, then dropping it",
    "Größe: ünïcödé text, numbers 12345 and punctuation!?",
    "word " * (MINILM_MAX_TOKENS + 50),  # longer than the model's window: truncated alike
]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("onnx")
    export_minilm(out)
    export_touch(out)
    return out


def test_minilm_onnx_matches_torch(folder: Path) -> None:
    want = MiniLMSpace(cache_size=0).embed_texts(TEXTS)  # (N, 384)
    got = OnnxMiniLM(folder).embed_texts(TEXTS)
    assert got.shape == want.shape == (len(TEXTS), 384)
    assert np.abs(got - want).max() < 1e-4
    assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-5)
    # one batch or one text at a time: padding does not change a text's vector
    alone = np.concatenate([OnnxMiniLM(folder).embed_texts([t]) for t in TEXTS])
    assert np.abs(alone - got).max() < 1e-4


def test_touch_onnx_matches_torch(folder: Path) -> None:
    enc = TactusEncoder()
    onnx = OnnxTouch(folder)
    assert (onnx.frames, onnx.dim) == (enc.frames, enc.dim)
    rng = np.random.default_rng(0)
    raw = np.full((6, enc.frames, 32, 32), 512, np.int16)  # (B, K, 32, 32) raw sensor units
    raw[:, :, 8:24, 6:20] += rng.integers(0, 300, (6, enc.frames, 16, 14)).astype(np.int16)
    want = enc.embed(raw)  # validation + calibration + torch
    calibrated = np.stack([enc.validate(w, keep_idle=True) for w in raw]).astype(np.float32)
    got = onnx.embed(calibrated)
    assert got.shape == want.shape
    assert np.abs(got - want).max() < 1e-4
    assert np.abs(got[0] - got[1]).max() > 1e-3  # different windows, different vectors


def test_touch_export_of_another_checkpoint_is_refused(folder: Path, tmp_path: Path) -> None:
    for f in folder.iterdir():
        (tmp_path / f.name).symlink_to(f)
    with pytest.raises(InvalidInputError, match="exported from checkpoint"):
        OnnxTouch(tmp_path, checkpoint_sha256="0" * 64)


def test_serve_on_onnx_without_torch(folder: Path, tmp_path: Path) -> None:
    """`tactus serve --onnx DIR`: both encoders on ONNX Runtime, torch never loaded; a touch
    window and a note are stored and found by text."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp_path / "serve.log"
    env = {"TACTUS_TORCH_THREADS": "1"}  # a torch setting must not bring torch in
    proc = start_serve(port, tmp_path / "mem", log, "--onnx", str(folder), env=env)
    try:
        hits, maps = touch_and_note_found(proc, base, log, 120)  # maps after writes, a search
        assert "onnxruntime" in maps
        assert "libtorch" not in maps
        assert {h["sense"] for h in hits} == {"text", "touch"}
        assert hits[0]["sense"] == "text"
    finally:
        stop_process(proc)


def test_a_pickled_onnx_space_stays_on_onnx(tmp_path: Path) -> None:
    """Ray workers get the space pickled: its ONNX folder goes with it (a space that came
    back on torch would load another runtime and, without torch, fail)."""
    import pickle

    space = MiniLMSpace(onnx=tmp_path, batch_size=7)
    back = pickle.loads(pickle.dumps(space))
    assert (back.onnx, back.path, back.batch_size) == (tmp_path, None, 7)
