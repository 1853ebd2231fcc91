"""The default server's ONNX models: a folder in the user's cache that ``tactus serve`` runs
on ONNX Runtime (:mod:`tactus_memory.spaces.onnx_runtime`), torch never imported by the server.

* The touch encoder: the shipped checkpoint's graph ships with the package
  (``touch/checkpoints/tactus-lite-minilm.onnx``, checked against torch by
  ``tests/spaces/test_onnx_default.py``) and is copied in; another checkpoint is exported.
* MiniLM: exported once, on the first start, in a child process (torch is loaded there, never
  in the server), and checked against torch before the folder is used.

The folder is named by what its graphs come from (MiniLM's weights file and the touch
checkpoint's sha256), so a new model or checkpoint gets a new folder. It appears complete or
not at all (written beside it, then renamed), and ``checked.json`` records the check.

    python -m tactus_memory.export.cache FOLDER [--touch-checkpoint PATH]   (what serve runs)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from tactus_memory.export.user_cache import cache_root
from tactus_memory.spaces.onnx_runtime import TOUCH_ONNX, TOUCH_SOURCE

#: bump when the export changes what it writes: a new cache folder, exported again
EXPORT_VERSION = 1
#: written last, into a folder whose graphs were checked against torch
CHECKED = "checked.json"
#: beside the shipped checkpoint: its ONNX graph, and the record of what it was exported from
SHIPPED_ONNX = "tactus-lite-minilm.onnx"
SHIPPED_SOURCE = "tactus-lite-minilm.onnx.json"
#: the largest difference to torch's vectors an export may show (measured ~1e-7)
TOLERANCE = 1e-4
CHECK_TEXTS = [
    "where did I put the red mug?",
    "x",
    "squeezing a tennis ball gently with two fingers on the kitchen table",
]


def shipped_onnx() -> tuple[Path, dict[str, str]]:
    """The shipped touch checkpoint's graph and its source record."""
    from tactus_memory.touch.checkpoint import default_checkpoint_path

    folder = default_checkpoint_path().parent
    return folder / SHIPPED_ONNX, json.loads((folder / SHIPPED_SOURCE).read_text())


def _minilm_key() -> str:
    """Which MiniLM the export is of: the bundled folder and its weights file's size and
    modification time (no read of the 90 MB), and the export's version."""
    from tactus_memory.spaces.minilm import default_model_path

    path = default_model_path()
    weights = sorted(path.glob("*.safetensors")) or sorted(path.glob("*.bin"))
    stamp = [str(path), EXPORT_VERSION]
    for w in weights:
        st = w.stat()
        stamp += [w.name, st.st_size, st.st_mtime_ns]
    return hashlib.sha256(json.dumps(stamp).encode()).hexdigest()[:12]


def default_folder(touch_checkpoint: str | os.PathLike[str] | None = None) -> Path:
    """The cache folder for MiniLM and ``touch_checkpoint`` (None: the shipped one)."""
    from tactus_memory.hashing import file_sha256

    if touch_checkpoint is None:
        touch = shipped_onnx()[1]["checkpoint_sha256"]
    else:
        touch = file_sha256(Path(touch_checkpoint))
    return cache_root() / "onnx" / f"minilm-{_minilm_key()}-touch-{touch[:12]}"


def is_ready(folder: Path) -> bool:
    return (folder / CHECKED).is_file()


def prepare(
    folder: Path,
    touch_checkpoint: str | os.PathLike[str] | None = None,
    say: Callable[[str], None] = lambda line: None,
) -> Path:
    """``folder`` complete and checked: exported now in a child process (torch loads there)
    unless it is already; one process exports while others wait on a lock file."""
    if is_ready(folder):
        return folder
    import fcntl

    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / (folder.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several workers starting at once: one exports
        if is_ready(folder):
            return folder
        say(f"exporting MiniLM to ONNX once, into {folder} (torch, in a child process)")
        cmd = [sys.executable, "-m", "tactus_memory.export.cache", str(folder)]
        if touch_checkpoint is not None:
            cmd += ["--touch-checkpoint", str(touch_checkpoint)]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0 or not is_ready(folder):
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
            raise RuntimeError(f"the ONNX export into {folder} failed: {tail[0]} (or use --torch)")
    return folder


def _max_diff(a: object, b: object) -> float:
    import numpy as np

    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return float("inf")
    return float(np.abs(a - b).max())


def export(folder: Path, touch_checkpoint: str | None = None) -> dict[str, object]:
    """Write ``folder`` (MiniLM exported, the touch graph copied or exported), each graph
    checked against torch; returns the check's record."""
    import numpy as np

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.export.onnx import export_minilm, export_touch
    from tactus_memory.spaces.minilm import MiniLMSpace
    from tactus_memory.spaces.onnx_runtime import OnnxMiniLM, OnnxTouch

    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
    try:
        export_minilm(tmp)
        minilm = _max_diff(
            OnnxMiniLM(tmp).embed_texts(CHECK_TEXTS),
            MiniLMSpace(cache_size=0).embed_texts(CHECK_TEXTS),
        )
        graph, source = shipped_onnx()
        enc = TactusEncoder(touch_checkpoint)
        if touch_checkpoint is None or enc.ckpt.sha256 == source["checkpoint_sha256"]:
            shutil.copyfile(graph, tmp / TOUCH_ONNX)
            (tmp / TOUCH_SOURCE).write_text(json.dumps(source, indent=2) + "\n")
        else:
            export_touch(tmp, touch_checkpoint)
        rng = np.random.default_rng(0)
        raw = np.full((4, enc.frames, 32, 32), 512, np.int16)
        raw[:, :, 8:24, 6:20] += rng.integers(0, 300, (4, enc.frames, 16, 14)).astype(np.int16)
        calibrated = np.stack([enc.validate(w, keep_idle=True) for w in raw]).astype(np.float32)
        touch = _max_diff(
            OnnxTouch(tmp, checkpoint_sha256=enc.ckpt.sha256).embed(calibrated), enc.embed(raw)
        )
        record: dict[str, object] = {"minilm_max_abs_diff": minilm, "touch_max_abs_diff": touch}
        if not (minilm < TOLERANCE and touch < TOLERANCE):
            raise RuntimeError(f"the ONNX graphs do not give torch's vectors: {record}")
        (tmp / CHECKED).write_text(json.dumps(record, indent=2) + "\n")
        if folder.exists():  # an incomplete one (a crashed export): replaced
            shutil.rmtree(folder)
        os.replace(tmp, folder)
        return record
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m tactus_memory.export.cache")
    ap.add_argument("folder")
    ap.add_argument("--touch-checkpoint", default=None)
    args = ap.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    print(json.dumps(export(Path(args.folder), args.touch_checkpoint)))


if __name__ == "__main__":
    main()
