"""MiniLM's ONNX graph written from its safetensors weights with ``onnx`` alone (no torch):
what a server installed without the ``train`` extra exports on its first start.

The graph is BERT (``config.json``: 6 layers, 12 heads, hidden 384, exact-erf GELU, post-LN)
followed by sentence-transformers' mean pooling over the attention mask and L2
normalisation, as :func:`tactus_memory.export.onnx.export_minilm` traces it from torch:

    (input_ids, attention_mask, token_type_ids) (B, T) int64 -> embedding (B, 384) float32

``tests/spaces/test_minilm_graph.py`` checks its vectors against sentence-transformers'.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

#: ONNX opset of the graph (LayerNormalization is an operator from 17 on; ORT 1.17+ runs it)
OPSET = 17
INPUTS = ("input_ids", "attention_mask", "token_type_ids")


class _Graph:
    """Nodes and initializers, each value named once."""

    def __init__(self) -> None:
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self._n = 0

    def const(self, name: str, value: np.ndarray) -> str:
        from onnx import numpy_helper

        self.inits.append(numpy_helper.from_array(np.ascontiguousarray(value), name))
        return name

    def op(self, kind: str, *inputs: str, **attrs: Any) -> str:
        from onnx import helper

        self._n += 1
        out = f"{kind.lower()}_{self._n}"
        self.nodes.append(helper.make_node(kind, list(inputs), [out], **attrs))
        return out

    def linear(self, x: str, w: np.ndarray, b: np.ndarray, name: str) -> str:
        """x (..., in) @ W.T + b, W (out, in) as torch's nn.Linear keeps it."""
        wt = self.const(name + ".wt", w.T.astype(np.float32))
        return self.op("Add", self.op("MatMul", x, wt), self.const(name + ".b", b))

    def layer_norm(self, x: str, w: dict[str, np.ndarray], name: str, eps: float) -> str:
        scale = self.const(name + ".g", w[name + ".weight"])
        bias = self.const(name + ".b", w[name + ".bias"])
        return self.op("LayerNormalization", x, scale, bias, axis=-1, epsilon=eps)


def _one_int64() -> Any:
    from onnx import TensorProto, helper

    return helper.make_tensor("one", TensorProto.INT64, [1], [1])


def build_minilm(model_path: str | os.PathLike[str]) -> Any:
    """The ONNX ModelProto of the sentence-transformers folder ``model_path`` (a BERT with
    mean pooling and normalisation, as all-MiniLM-L6-v2)."""
    from onnx import TensorProto, helper
    from safetensors.numpy import load_file

    folder = Path(model_path)
    cfg = json.loads((folder / "config.json").read_text())
    w = load_file(str(folder / "model.safetensors"))
    hidden, heads = int(cfg["hidden_size"]), int(cfg["num_attention_heads"])
    head_dim, eps = hidden // heads, float(cfg["layer_norm_eps"])
    g = _Graph()
    i64 = lambda name, v: g.const(name, np.array(v, np.int64))  # noqa: E731
    f32 = lambda name, v: g.const(name, np.array(v, np.float32))  # noqa: E731
    ids, mask, types = INPUTS

    # embeddings: word + position (0..T-1) + token type, then LayerNorm   (B, T, H)
    ones = g.op("ConstantOfShape", g.op("Shape", ids), value=_one_int64())  # (B, T)
    positions = g.op("Sub", g.op("CumSum", ones, i64("axis_tokens", 1)), ones)  # 0..T-1 (B, T)
    x = g.op(
        "Add",
        g.op(
            "Add",
            g.op("Gather", g.const("word", w["embeddings.word_embeddings.weight"]), ids),
            g.op("Gather", g.const("type", w["embeddings.token_type_embeddings.weight"]), types),
        ),
        g.op("Gather", g.const("pos", w["embeddings.position_embeddings.weight"]), positions),
    )
    x = g.layer_norm(x, w, "embeddings.LayerNorm", eps)

    # the attention mask as an additive bias (B, 1, 1, T): 0 where kept, float32's min where padded
    maskf = g.op("Cast", mask, to=TensorProto.FLOAT)  # (B, T)
    bias = g.op("Mul", g.op("Sub", f32("one", 1.0), maskf), f32("min", np.finfo(np.float32).min))
    bias = g.op("Unsqueeze", bias, i64("axes_12", [1, 2]))
    split = i64("split_heads", [0, 0, heads, head_dim])
    merge = i64("merge_heads", [0, 0, hidden])
    scale = f32("scale", 1.0 / np.sqrt(head_dim))

    for i in range(int(cfg["num_hidden_layers"])):
        p = f"encoder.layer.{i}."

        def heads_of(name: str, perm: list[int], p: str = p, x: str = x) -> str:
            y = g.linear(x, w[p + name + ".weight"], w[p + name + ".bias"], p + name)
            return g.op("Transpose", g.op("Reshape", y, split), perm=perm)

        q = heads_of("attention.self.query", [0, 2, 1, 3])  # (B, h, T, d)
        k = heads_of("attention.self.key", [0, 2, 3, 1])  # (B, h, d, T)
        v = heads_of("attention.self.value", [0, 2, 1, 3])  # (B, h, T, d)
        scores = g.op("Add", g.op("Mul", g.op("MatMul", q, k), scale), bias)  # (B, h, T, T)
        ctx = g.op("MatMul", g.op("Softmax", scores, axis=-1), v)  # (B, h, T, d)
        ctx = g.op("Reshape", g.op("Transpose", ctx, perm=[0, 2, 1, 3]), merge)  # (B, T, H)
        name = p + "attention.output.dense"
        attn = g.linear(ctx, w[name + ".weight"], w[name + ".bias"], name)
        x = g.layer_norm(g.op("Add", attn, x), w, p + "attention.output.LayerNorm", eps)
        name = p + "intermediate.dense"
        y = g.linear(x, w[name + ".weight"], w[name + ".bias"], name)  # (B, T, 4H)
        # exact GELU: 0.5 y (1 + erf(y / sqrt 2)), BERT's "gelu"
        erf = g.op("Erf", g.op("Div", y, f32(p + "sqrt2", np.sqrt(2.0))))
        y = g.op("Mul", g.op("Mul", y, f32(p + "half", 0.5)), g.op("Add", erf, "one"))
        name = p + "output.dense"
        out = g.linear(y, w[name + ".weight"], w[name + ".bias"], name)
        x = g.layer_norm(g.op("Add", out, x), w, p + "output.LayerNorm", eps)

    # mean over the kept tokens, then unit rows   (B, H)
    m = g.op("Unsqueeze", maskf, i64("axis_last", [-1]))  # (B, T, 1)
    axes = i64("reduce_tokens", [1])
    summed = g.op("ReduceSum", g.op("Mul", x, m), axes, keepdims=0)
    count = g.op("Max", g.op("ReduceSum", m, axes, keepdims=0), f32("tiny", 1e-9))
    pooled = g.op("Div", summed, count)
    norm = g.op("Max", g.op("ReduceL2", pooled, axes=[-1], keepdims=1), f32("eps_norm", 1e-12))
    g.nodes.append(helper.make_node("Div", [pooled, norm], ["embedding"]))

    graph = helper.make_graph(
        g.nodes,
        "minilm",
        [helper.make_tensor_value_info(n, TensorProto.INT64, ["batch", "tokens"]) for n in INPUTS],
        [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["batch", hidden])],
        g.inits,
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])


def write_minilm(
    out: str | os.PathLike[str], model_path: str | os.PathLike[str] | None = None
) -> Path:
    """MiniLM (``model_path``, default the bundled folder) -> ``out/minilm.onnx`` with its
    weights in ``out/minilm.onnx.data``, and ``out/tokenizer.json``; returns ``out``."""
    import shutil

    import onnx

    from tactus_memory.spaces.minilm import MiniLMSpace
    from tactus_memory.spaces.onnx_runtime import MINILM_ONNX, MINILM_WEIGHTS, TOKENIZER_JSON

    path = MiniLMSpace(model_path)._resolve_path()  # noqa: SLF001
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MINILM_WEIGHTS).unlink(missing_ok=True)  # onnx appends to an existing data file
    onnx.save_model(
        build_minilm(path),
        str(folder / MINILM_ONNX),
        save_as_external_data=True,
        all_tensors_to_one_file=True,
        location=MINILM_WEIGHTS,
        size_threshold=1024,
    )
    shutil.copyfile(path / TOKENIZER_JSON, folder / TOKENIZER_JSON)
    return folder
