"""The default server's ONNX models: a folder in the user's cache that ``tactus serve`` runs
on ONNX Runtime (:mod:`tactus_memory.spaces.onnx_runtime`), torch never imported by the server.

* The touch encoder: each shipped checkpoint's graph ships with the package
  (``touch/checkpoints/tactus-lite-minilm.onnx``, and ``tactus-lite-minilm-demo.onnx`` for
  ``tactus demo``; checked against torch by ``tests/spaces/test_onnx_default.py``) and is
  copied in; another checkpoint is exported.
* MiniLM: its graph is written once, on the first start, from its safetensors weights with
  ``onnx`` alone (:mod:`tactus_memory.export.minilm_graph`), in a child process, and checked
  before the folder is used: against torch where the ``train`` extra is installed, else against
  the vectors shipped beside this module (``minilm_reference.json``, computed on torch).

The folder is named by what its graphs come from (MiniLM's weights file and the touch
checkpoint's sha256), so a new model or checkpoint gets a new folder. It appears complete or
not at all (written beside it, then renamed), and ``checked.json`` records the check.

    python -m tactus_memory.export.cache FOLDER [--touch-checkpoint PATH]   (what serve runs)
    python -m tactus_memory.export.cache --default [--touch-checkpoint PATH]
        the default folder, prepared, its path printed: what a process without torch runs
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
from typing import TYPE_CHECKING

from tactus_memory.export.user_cache import cache_root
from tactus_memory.spaces.onnx_runtime import TOUCH_ONNX, TOUCH_SOURCE, has_torch

if TYPE_CHECKING:  # annotations only: numpy is imported inside the functions that use it
    import numpy as np

#: bump when the export changes what it writes: a new cache folder, exported again
EXPORT_VERSION = 2
#: written last, into a folder whose graphs were checked (against torch, or the reference)
CHECKED = "checked.json"
#: beside the shipped checkpoint: its ONNX graph, and the record of what it was exported from;
#: every shipped checkpoint (the demo's too) has its graph beside it, named like it
SHIPPED_ONNX = "tactus-lite-minilm.onnx"
SHIPPED_SOURCE = "tactus-lite-minilm.onnx.json"
#: the name of a shipped graph's source record, after the graph's (``<stem>.onnx.json``)
SOURCE_SUFFIX = ".json"
#: the largest difference to torch's vectors an export may show (measured ~1e-7)
TOLERANCE = 1e-4
#: beside this module: MiniLM's vectors of CHECK_TEXTS computed on torch, for a check without it
REFERENCE = "minilm_reference.json"
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


def shipped_graph(checkpoint_sha256: str) -> tuple[Path, dict[str, str]] | None:
    """The graph that ships for the checkpoint of ``checkpoint_sha256`` (the default or the
    demo checkpoint: each has ``<stem>.onnx`` and its source record beside it), or None: a
    user's checkpoint is exported (which needs torch)."""
    folder = shipped_onnx()[0].parent
    for record in sorted(folder.glob("*.onnx" + SOURCE_SUFFIX)):
        source = json.loads(record.read_text())
        graph = record.with_name(record.name.removesuffix(SOURCE_SUFFIX))
        if source.get("checkpoint_sha256") == checkpoint_sha256 and graph.is_file():
            return graph, source
    return None


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
    """``folder`` complete and checked: exported now in a child process (torch, if installed,
    loads there for the check)
    unless it is already; one process exports while others wait on a lock file."""
    if is_ready(folder):
        return folder
    import fcntl

    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / (folder.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several workers starting at once: one exports
        if is_ready(folder):
            return folder
        say(f"exporting MiniLM to ONNX once, into {folder} (in a child process)")
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


def reference_vectors() -> tuple[list[str], np.ndarray]:
    """The shipped MiniLM vectors of :data:`CHECK_TEXTS` (computed on torch; checked equal to
    sentence-transformers' by tests/spaces/test_minilm_graph.py): (texts, (N, 384) array)."""
    import numpy as np

    ref = json.loads((Path(__file__).parent / REFERENCE).read_text())
    return list(ref["texts"]), np.asarray(ref["vectors"], np.float32)


def export(folder: Path, touch_checkpoint: str | None = None) -> dict[str, object]:
    """Write ``folder`` (MiniLM's graph written from its weights, the touch graph copied or
    exported), each graph checked against torch where it is installed (the ``train`` extra),
    else MiniLM against the shipped reference vectors and the shipped touch graph as the
    package's tests checked it; returns the check's record."""
    import numpy as np

    from tactus_memory.export.minilm_graph import write_minilm
    from tactus_memory.spaces.onnx_runtime import OnnxMiniLM, OnnxTouch
    from tactus_memory.touch.checkpoint import load_checkpoint

    torch = has_torch()
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
    try:
        write_minilm(tmp)
        if torch:
            from tactus_memory.spaces.minilm import MiniLMSpace

            want = MiniLMSpace(cache_size=0).embed_texts(CHECK_TEXTS)
            texts = CHECK_TEXTS
        else:
            texts, want = reference_vectors()
        minilm = _max_diff(OnnxMiniLM(tmp).embed_texts(texts), want)
        shipped = (
            shipped_onnx()
            if touch_checkpoint is None
            else shipped_graph(load_checkpoint(touch_checkpoint, weights=False).sha256)
        )
        if shipped is not None:
            graph, source = shipped
            shutil.copyfile(graph, tmp / TOUCH_ONNX)
            (tmp / TOUCH_SOURCE).write_text(json.dumps(source, indent=2) + "\n")
        elif torch:
            from tactus_memory.export.onnx import export_touch

            export_touch(tmp, touch_checkpoint)
        else:
            raise RuntimeError(
                f"exporting the touch checkpoint {touch_checkpoint} to ONNX needs torch: "
                "pip install 'tactus-memory[train]'"
            )
        touch: float | str = "the shipped graph (checked against torch by the package's tests)"
        if torch:
            from tactus_memory.adapters.touch import TactusEncoder

            enc = TactusEncoder(touch_checkpoint)
            rng = np.random.default_rng(0)
            raw = np.full((4, enc.frames, 32, 32), 512, np.int16)
            raw[:, :, 8:24, 6:20] += rng.integers(0, 300, (4, enc.frames, 16, 14)).astype(np.int16)
            calibrated = np.stack([enc.validate(w, keep_idle=True) for w in raw])
            touch = _max_diff(
                OnnxTouch(tmp, checkpoint_sha256=enc.ckpt.sha256).embed(
                    calibrated.astype(np.float32)
                ),
                enc.embed(raw),
            )
        record: dict[str, object] = {
            "minilm_max_abs_diff": minilm,
            "touch_max_abs_diff": touch,
            "torch": torch,
        }
        if not (minilm < TOLERANCE and (not isinstance(touch, float) or touch < TOLERANCE)):
            raise RuntimeError(f"the ONNX graphs do not give the expected vectors: {record}")
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
    ap.add_argument("folder", nargs="?", help="export into FOLDER (default: --default's)")
    ap.add_argument("--touch-checkpoint", default=None)
    ap.add_argument(
        "--default",
        action="store_true",
        help="prepare the default folder (exported once) and print its path "
        "(tactus_memory.spaces.onnx_runtime.default_onnx_folder runs this)",
    )
    args = ap.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    if args.default or args.folder is None:
        folder = default_folder(args.touch_checkpoint)
        print(prepare(folder, args.touch_checkpoint))
        return
    print(json.dumps(export(Path(args.folder), args.touch_checkpoint)))


if __name__ == "__main__":
    main()
