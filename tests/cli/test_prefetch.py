"""The start's read-ahead (:mod:`tactus_memory.cli.prefetch`): the list a ready process
records, its order, and reading it ahead (real files: LanceDB's Rust library, this test)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactus_memory.cli import prefetch

needs_fadvise = pytest.mark.skipif(
    not hasattr(os, "posix_fadvise"), reason="the read-ahead acts where posix_fadvise exists"
)


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The user's cache in ``tmp_path``, the read-ahead on."""
    monkeypatch.setenv("TACTUS_CACHE", str(tmp_path))
    monkeypatch.delenv(prefetch.ENV, raising=False)
    return tmp_path


def lancedb_library() -> Path:
    """LanceDB's Rust library, found as the read-ahead finds files: no import."""
    spec = importlib.util.find_spec("lancedb")
    assert spec is not None and spec.origin is not None
    found = sorted(Path(spec.origin).parent.glob("_lancedb*.so"))
    assert found, "lancedb's shared library"
    return found[0]


@needs_fadvise
def test_read_ahead_asks_for_the_files_there_and_skips_the_missing(tmp_path: Path) -> None:
    library = lancedb_library()
    missing = tmp_path / "gone.so"
    assert prefetch.read_ahead([str(missing), str(library)]) == 1
    assert prefetch.read_ahead([]) == 0


def test_the_list_keeps_import_order_and_puts_a_library_before_its_package() -> None:
    modules = [
        "/sp/numpy/__pycache__/__init__.pyc",
        "/sp/pyarrow/__pycache__/__init__.pyc",
        "/sp/pyarrow/lib.so",
        "/sp/numpy/__pycache__/__init__.pyc",  # listed once
    ]
    mapped = [
        "/sp/pyarrow/lib.so",  # a module already
        "/sp/pyarrow/libarrow.so.2600",
        "/sp/numpy.libs/libopenblas.so",
        "/usr/lib/libc.so.6",
    ]
    assert prefetch.start_files(modules, mapped) == [
        "/sp/numpy.libs/libopenblas.so",
        "/sp/numpy/__pycache__/__init__.pyc",
        "/sp/pyarrow/libarrow.so.2600",
        "/sp/pyarrow/__pycache__/__init__.pyc",
        "/sp/pyarrow/lib.so",
        "/usr/lib/libc.so.6",
    ]


def test_the_list_ends_with_the_model_folders_files(tmp_path: Path) -> None:
    (tmp_path / "minilm.onnx").write_bytes(b"graph")
    (tmp_path / "minilm.onnx.data").write_bytes(b"weights")
    (tmp_path / "sub").mkdir()
    mapped = [str(tmp_path / "minilm.onnx.data")]
    assert prefetch.start_files(["/sp/a.pyc"], mapped, [tmp_path]) == [
        "/sp/a.pyc",
        str(tmp_path / "minilm.onnx.data"),
        str(tmp_path / "minilm.onnx"),
    ]


def test_mapped_files_reads_the_maps_text() -> None:
    maps = (
        "7f00-7f01 r--p 00000000 fd:01 12 /sp/lance/lance.abi3.so\n"
        "7f01-7f02 r-xp 00001000 fd:01 12 /sp/lance/lance.abi3.so\n"
        "7f02-7f03 rw-p 00000000 00:00 0 \n"
        "7f03-7f04 rw-p 00000000 00:00 0 [heap]\n"
        "7f04-7f05 r--p 00000000 fd:01 13 /tmp/x (deleted)\n"
        "7f05-7f06 r--p 00000000 fd:01 14 /sp/a b.so\n"
    )
    assert prefetch._mapped_files(maps) == ["/sp/a b.so", "/sp/lance/lance.abi3.so"]


def test_a_ready_process_records_its_list_and_the_next_serve_reads_it(cache: Path) -> None:
    assert prefetch.start(["tactus", "serve"]) is False  # a first start: no list yet
    assert prefetch.record() is True
    listed = prefetch.list_path().read_text().splitlines()
    assert prefetch.list_path().parent == cache / "prefetch"
    # this module, as a start reads it: its bytecode (its source where none was written)
    assert prefetch.__spec__.cached in listed or prefetch.__file__ in listed
    assert prefetch.record() is False  # unchanged: not written again
    assert prefetch.start(["tactus", "search", "mug"]) is False  # only serve reads ahead
    # serve, in a fresh process (the reader is forked): started, and the command's output
    # (a pipe here) is not held open by it
    code = "from tactus_memory.cli import prefetch; print(prefetch.start(['tactus', 'serve']))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.strip() == "True"


@needs_fadvise
def test_bytecode_whose_source_is_gone_is_still_read(tmp_path: Path) -> None:
    cached = tmp_path / "__pycache__" / "gone.cpython-311.pyc"
    cached.parent.mkdir()
    cached.write_bytes(b"bytecode")
    assert prefetch.read_ahead([str(cached), str(tmp_path / "__pycache__" / "x.pyc")]) == 1


def test_turned_off_it_neither_records_nor_reads(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(prefetch.ENV, "0")
    assert prefetch.record() is False
    assert not (cache / "prefetch").exists()
    monkeypatch.delenv(prefetch.ENV)
    prefetch.record()
    monkeypatch.setenv(prefetch.ENV, "0")
    assert prefetch.start(["tactus", "serve"]) is False


def test_an_unwritable_cache_is_no_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("TACTUS_CACHE", str(blocker))
    monkeypatch.delenv(prefetch.ENV, raising=False)
    assert prefetch.record() is False
    assert prefetch.start(["tactus", "serve"]) is False
