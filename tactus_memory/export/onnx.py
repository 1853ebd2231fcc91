"""Export the two serving encoders to ONNX (the optional extra ``[onnx]``; needs torch):

* MiniLM (``all-MiniLM-L6-v2``, the default space): BERT + mean pooling over the attention
  mask + L2 normalisation, as sentence-transformers computes it, in one graph
  ``(input_ids, attention_mask, token_type_ids) (B, T) int64 -> (B, 384) float32``; the
  tokenizer is the model folder's own ``tokenizer.json``, copied beside the graph.
* The touch encoder (the shipped Tactus checkpoint or another one):
  ``frames (B, K, 32, 32) float32, calibrated -> (B, D) float32``.

Run them with :mod:`tactus_memory.spaces.onnx_runtime` (ONNX Runtime only, no torch). The graphs are
checked against the torch models by ``tests/spaces/test_onnx_export.py``; start time and memory of
both runtimes are compared in ``benchmarks/light_server.py``.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from tactus_memory.spaces.onnx_runtime import (
    MINILM_ONNX,
    MINILM_WEIGHTS,
    TOKENIZER_JSON,
    TOUCH_ONNX,
    TOUCH_SOURCE,
)

#: ONNX opset of the exported graphs (ONNX Runtime 1.17+ runs it)
OPSET = 17


def _export(module: object, args: tuple[object, ...], path: Path, names: dict[str, Any]) -> None:
    import torch

    torch.onnx.export(
        module,
        args,
        str(path),
        input_names=list(names["inputs"]),
        output_names=["embedding"],
        dynamic_axes=names["axes"],
        opset_version=OPSET,
        dynamo=False,  # the TorchScript exporter: one self-contained file, no onnxscript
    )


def export_minilm(
    out: str | os.PathLike[str], model_path: str | os.PathLike[str] | None = None
) -> Path:
    """MiniLM (the local sentence-transformers folder ``model_path``, default the bundled
    one) -> ``out/minilm.onnx`` and ``out/tokenizer.json``; returns ``out``."""
    import torch

    from tactus_memory.spaces.minilm import MiniLMSpace

    space = MiniLMSpace(model_path)
    st = space._get_model()  # noqa: SLF001  (the loaded sentence-transformers model)
    bert = st[0].auto_model.eval()

    class MeanPooled(torch.nn.Module):
        """BERT -> masked mean over tokens -> unit rows, as sentence-transformers does."""

        def __init__(self) -> None:
            super().__init__()
            self.bert = bert

        def forward(
            self, ids: torch.Tensor, mask: torch.Tensor, types: torch.Tensor
        ) -> torch.Tensor:
            h = self.bert(input_ids=ids, attention_mask=mask, token_type_ids=types)[0]
            m = mask.unsqueeze(-1).to(h.dtype)  # (B, T, 1)
            pooled = (h * m).sum(1) / m.sum(1).clamp(min=1e-9)
            return torch.nn.functional.normalize(pooled, dim=-1)  # (B, 384)

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    ids = torch.ones((2, 8), dtype=torch.int64)
    axes = {n: {0: "batch", 1: "tokens"} for n in ("input_ids", "attention_mask", "token_type_ids")}
    names = {"inputs": list(axes), "axes": {**axes, "embedding": {0: "batch"}}}
    graph = folder / (MINILM_ONNX + ".tmp")
    with torch.inference_mode():
        _export(MeanPooled().eval(), (ids, ids, torch.zeros_like(ids)), graph, names)
    _weights_outside(graph, folder / MINILM_ONNX, MINILM_WEIGHTS)
    shutil.copyfile(space._resolve_path() / TOKENIZER_JSON, folder / TOKENIZER_JSON)  # noqa: SLF001
    return folder


def _weights_outside(graph: Path, out: Path, weights: str) -> None:
    """Rewrite the ONNX file ``graph`` as ``out`` with its weights in ``weights`` beside it."""
    import onnx

    model = onnx.load(str(graph))
    (out.parent / weights).unlink(missing_ok=True)  # onnx appends to an existing data file
    onnx.save_model(
        model,
        str(out),
        save_as_external_data=True,
        all_tensors_to_one_file=True,
        location=weights,
        size_threshold=1024,
    )
    graph.unlink()


def export_touch(
    out: str | os.PathLike[str], checkpoint: str | os.PathLike[str] | None = None
) -> Path:
    """The touch encoder of ``checkpoint`` (default the shipped one) -> ``out/touch.onnx``."""
    import torch

    from tactus_memory.touch.checkpoint import default_checkpoint_path, load_checkpoint

    ckpt = load_checkpoint(checkpoint or default_checkpoint_path())
    assert ckpt.model is not None  # load_checkpoint builds the model
    model = ckpt.model.eval()
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    # (2, K, H, W): the sensor's frame shape, as its profile records it (the glove: 32x32)
    shape = ckpt.meta.get("calibration", {}).get("shape") or model.cfg.frame_shape
    frames = torch.rand(2, model.cfg.frames, *(int(v) for v in shape))
    names = {"inputs": ["frames"], "axes": {"frames": {0: "batch"}, "embedding": {0: "batch"}}}
    with torch.inference_mode():
        _export(model, (frames,), folder / TOUCH_ONNX, names)
    source = {"checkpoint": ckpt.path.name, "checkpoint_sha256": ckpt.sha256}
    (folder / TOUCH_SOURCE).write_text(json.dumps(source, indent=2) + "\n")
    return folder
