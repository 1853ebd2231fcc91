"""The serving encoders on ONNX Runtime, without torch (graphs written by
:mod:`tactus_memory.export.onnx`; the optional extra ``[onnx]``).

* :class:`OnnxMiniLM`: texts -> (N, 384) float32 unit rows (the ``tokenizers`` library reads
  the model's own ``tokenizer.json``: truncation at 256 tokens as sentence-transformers).
* :class:`OnnxTouch`: calibrated windows (B, K, 32, 32) float32 -> (B, D) float32 unit rows.

Each session runs on ``threads`` intra-op threads (default 1: a robot's small computer has
few cores, and the server runs searches beside it).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.vectors import as_unit_rows

#: the files of an export folder (written by tactus_memory.export.onnx)
MINILM_ONNX = "minilm.onnx"
#: MiniLM's weights, beside the graph: ONNX Runtime maps this file instead of copying the
#: weights out of the graph, so a server's RSS holds only the pages it reads (about 90 MB
#: less at /ready, benchmarks/results/light_server.json)
MINILM_WEIGHTS = "minilm.onnx.data"
TOKENIZER_JSON = "tokenizer.json"
TOUCH_ONNX = "touch.onnx"
#: beside touch.onnx: the sha256 of the checkpoint it was exported from
TOUCH_SOURCE = "touch.json"
#: sentence-transformers' max_seq_length for all-MiniLM-L6-v2 (its sentence_bert_config.json)
MINILM_MAX_TOKENS = 256


def has_torch() -> bool:
    """Whether torch and sentence-transformers are installed (the ``train`` extra)."""
    import importlib.util

    try:
        return all(importlib.util.find_spec(m) for m in ("torch", "sentence_transformers"))
    except (ImportError, ValueError):  # blocked (sys.modules[name] = None, an import hook)
        return False


def default_onnx_folder(touch_checkpoint: str | os.PathLike[str] | None = None) -> Path:
    """The user cache's ONNX folder for MiniLM and ``touch_checkpoint`` (None: the shipped
    one), exported once if it is not there yet: what MiniLM and the touch sense run on where
    torch is not installed. A child process prepares it (the export layer sits above the
    models: :mod:`tactus_memory.export.cache`, as ``tactus serve`` uses it)."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "tactus_memory.export.cache", "--default"]
    if touch_checkpoint is not None:
        cmd += ["--touch-checkpoint", str(touch_checkpoint)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"preparing the ONNX models failed: {tail[0]}")
    return Path(lines[-1])


def _session(path: Path, threads: int) -> Any:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    # no arena: ORT's own pool keeps the peak of every batch for good (a server that embedded
    # 64 touch windows once stayed ~65 MB larger); plain malloc is handed back by malloc_trim
    opts.enable_cpu_mem_arena = False
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


class OnnxMiniLM:
    """MiniLM from ``folder`` (``minilm.onnx`` + ``tokenizer.json``)."""

    dim = 384

    def __init__(self, folder: str | os.PathLike[str], *, threads: int = 1) -> None:
        from tokenizers import Tokenizer

        folder = Path(folder)
        self.tokenizer = Tokenizer.from_file(str(folder / TOKENIZER_JSON))
        self.tokenizer.enable_truncation(MINILM_MAX_TOKENS)
        self.tokenizer.enable_padding()
        self.session = _session(folder / MINILM_ONNX, threads)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        """N strings -> (N, 384) float32 unit rows."""
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        enc = self.tokenizer.encode_batch(list(texts))
        feed = {
            "input_ids": np.array([e.ids for e in enc], np.int64),  # (N, T)
            "attention_mask": np.array([e.attention_mask for e in enc], np.int64),
            "token_type_ids": np.array([e.type_ids for e in enc], np.int64),
        }
        out = self.session.run(None, feed)[0]
        return as_unit_rows(out, self.dim, what="MiniLM embedding")


class OnnxTouch:
    """The touch encoder from ``folder/touch.onnx``; ``checkpoint_sha256``: refuse an export
    of another checkpoint (its ``touch.json`` records the source)."""

    def __init__(
        self,
        folder: str | os.PathLike[str],
        *,
        threads: int = 1,
        checkpoint_sha256: str | None = None,
    ) -> None:
        folder = Path(folder)
        if checkpoint_sha256 is not None:
            source = json.loads((folder / TOUCH_SOURCE).read_text())
            if source.get("checkpoint_sha256") != checkpoint_sha256:
                raise InvalidInputError(
                    f"{folder / TOUCH_ONNX} was exported from checkpoint "
                    f"{source.get('checkpoint')!r} (sha256 {source.get('checkpoint_sha256')}), "
                    f"not the one in use (sha256 {checkpoint_sha256}): export it again "
                    "(tactus_memory.export.onnx.export_touch)"
                )
        self.session = _session(folder / TOUCH_ONNX, threads)
        shape = self.session.get_inputs()[0].shape  # ["batch", K, 32, 32]
        self.frames = int(shape[1])
        self.dim = int(self.session.get_outputs()[0].shape[1])

    def embed(self, windows: np.ndarray) -> np.ndarray:
        """windows: (B, K, 32, 32) calibrated float32 -> (B, D) float32 unit rows."""
        x = np.ascontiguousarray(windows, np.float32)
        out = self.session.run(None, {"frames": x})[0]
        return as_unit_rows(out, self.dim, what="touch embedding")
