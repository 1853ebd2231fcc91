"""The light server is the default: the shipped touch checkpoint's ONNX graph (package data)
gives the torch encoder's vectors; ``tactus serve`` exports MiniLM once into the user's cache
(checked against torch, in a child process) and serves both on ONNX Runtime without loading
torch; ``--torch`` keeps the torch server."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from benchmarks.serving import free_port, start_serve, stop_process, wait_ok
from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.cli.serve_cmd import default_folder_of
from tactus_memory.export import cache as onnx_cache
from tactus_memory.hashing import file_sha256
from tactus_memory.settings import Settings
from tactus_memory.spaces.onnx_runtime import TOUCH_ONNX, TOUCH_SOURCE, OnnxTouch
from tactus_memory.touch.checkpoint import default_checkpoint_path, demo_checkpoint_path
from tests.helpers.servers import STARTUP_S, touch_and_note_found

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A user cache with the default folder exported into it (as on a first start)."""
    root = tmp_path_factory.mktemp("cache")
    old = os.environ.get("TACTUS_CACHE")
    os.environ["TACTUS_CACHE"] = str(root)
    try:
        folder = onnx_cache.default_folder()
        said: list[str] = []
        assert onnx_cache.prepare(folder, None, said.append) == folder
        assert said and "exporting MiniLM" in said[0]
    finally:
        if old is None:
            os.environ.pop("TACTUS_CACHE")
        else:
            os.environ["TACTUS_CACHE"] = old
    return root


@pytest.mark.parametrize("which", ["default", "demo"])
def test_the_shipped_touch_onnx_is_the_shipped_checkpoint(tmp_path: Path, which: str) -> None:
    """Each shipped checkpoint's graph (the demo's too: `tactus demo` runs without torch)."""
    path = default_checkpoint_path() if which == "default" else demo_checkpoint_path()
    found = onnx_cache.shipped_graph(file_sha256(path))
    assert found is not None, f"no graph ships for {path.name}"
    graph, source = found
    if which == "default":
        assert (graph, source) == onnx_cache.shipped_onnx()
    assert graph.is_file() and graph.stat().st_size < 20_000_000  # small: it ships
    assert source["checkpoint_sha256"] == file_sha256(path)
    assert onnx_cache.shipped_graph("0" * 64) is None  # a user's checkpoint: exported
    shutil.copyfile(graph, tmp_path / TOUCH_ONNX)
    (tmp_path / TOUCH_SOURCE).write_text(json.dumps(source))
    enc = TactusEncoder(path)
    onnx = OnnxTouch(tmp_path, checkpoint_sha256=enc.ckpt.sha256)
    rng = np.random.default_rng(1)
    raw = np.full((5, enc.frames, 32, 32), 512, np.int16)
    raw[:, :, 6:26, 4:22] += rng.integers(0, 400, (5, enc.frames, 20, 18)).astype(np.int16)
    want = enc.embed(raw)  # torch
    calibrated = np.stack([enc.validate(w, keep_idle=True) for w in raw]).astype(np.float32)
    got = onnx.embed(calibrated)
    assert got.shape == want.shape
    assert np.abs(got - want).max() < 1e-4
    assert np.abs(got[0] - got[1]).max() > 1e-3


def test_the_default_folder_is_exported_once_and_checked(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TACTUS_CACHE", str(cache))
    folder = onnx_cache.default_folder()
    assert folder.parent == cache / "onnx"
    checked = json.loads((folder / onnx_cache.CHECKED).read_text())
    assert checked["minilm_max_abs_diff"] < 1e-4 and checked["touch_max_abs_diff"] < 1e-4
    graph, _ = onnx_cache.shipped_onnx()
    assert (folder / TOUCH_ONNX).read_bytes() == graph.read_bytes()  # copied, not exported
    assert {p.name for p in folder.iterdir()} >= {"minilm.onnx", "minilm.onnx.data"}
    assert not [p for p in folder.parent.iterdir() if p.is_dir() and p != folder]  # no leftovers

    def no_export(*a: object, **k: object) -> None:
        raise AssertionError("exported again")

    monkeypatch.setattr(onnx_cache.subprocess, "run", no_export)
    assert onnx_cache.prepare(folder) == folder  # ready: nothing runs


def test_which_servers_get_the_default_folder(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("TACTUS_CACHE", str(tmp_path))
    folder = default_folder_of(Settings())
    assert folder is not None and folder.parent == tmp_path / "onnx"
    assert default_folder_of(Settings(torch=True)) is None
    assert default_folder_of(Settings(space="qwen3vl", space_path=str(tmp_path))) is None
    # another touch checkpoint: another folder (its graph is exported, not the shipped one)
    other = tmp_path / "other.safetensors"
    other.write_bytes(default_checkpoint_path().read_bytes() + b"\0")
    assert default_folder_of(Settings(touch_checkpoint=str(other))) not in (None, folder)
    # with touch off, the shipped graph's folder (nothing else is loaded from it)
    assert default_folder_of(Settings(touch=False)) == folder


def _serve(tmp_path: Path, cache: Path, *extra: str) -> tuple[object, str, Path]:
    port = free_port()
    log = tmp_path / "serve.log"
    env = {"TACTUS_CACHE": str(cache), "TACTUS_TORCH_THREADS": "1"}
    proc = start_serve(port, tmp_path / "mem", log, *extra, env=env)
    return proc, f"http://127.0.0.1:{port}", log


def test_tactus_serve_runs_on_onnx_runtime_by_default(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No flag: both encoders on ONNX Runtime from the cache, torch never loaded; a touch
    window and a note are stored and found by text."""
    proc, base, log = _serve(tmp_path, cache)
    try:
        hits, maps = touch_and_note_found(proc, base, log, 180)
        assert "onnxruntime" in maps and "libtorch" not in maps
        assert {h["sense"] for h in hits} == {"text", "touch"}
        started = log.read_text()
        monkeypatch.setenv("TACTUS_CACHE", str(cache))
        assert f"models run on:  ONNX Runtime ({onnx_cache.default_folder()})" in started, started
        assert "exporting MiniLM" not in started  # the cache had it
    finally:
        stop_process(proc)


def test_tactus_serve_torch_keeps_the_torch_server(cache: Path, tmp_path: Path) -> None:
    proc, base, log = _serve(tmp_path, cache, "--torch")
    try:
        assert wait_ok(proc, base + "/ready", STARTUP_S, interval=0.2) is not None, log.read_text()
        maps = Path(f"/proc/{proc.pid}/maps").read_text()
        assert "libtorch" in maps
        assert "models run on:  torch" in log.read_text()
    finally:
        stop_process(proc)
