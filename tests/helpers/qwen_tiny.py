"""Tiny random Qwen3-VL model folders for the end-to-end space tests.

``build_tiny_qwen3vl`` (tests/spaces/test_qwen3vl.py) saves a real local folder: config.json, the
safetensors weights, a byte-level BPE tokenizer with the Qwen special tokens and the image
processor config. :func:`perturbed_copy` makes "another model" of the same architecture (its
weights shifted), as a fine-tune or another download would be.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path

import numpy as np

from tactus_memory.spaces.qwen3vl import DOCUMENT_INSTRUCTION, QUERY_INSTRUCTION


def perturbed_copy(src: Path, dst: Path, *, scale: float = 0.05, seed: int = 1) -> Path:
    """Copy a model folder and add noise to every floating weight of its safetensors files."""
    import torch
    from safetensors import safe_open
    from safetensors.torch import save_file

    shutil.copytree(src, dst)
    gen = torch.Generator().manual_seed(seed)
    for weights in sorted(dst.glob("*.safetensors")):
        with safe_open(str(weights), framework="pt") as f:
            meta = f.metadata()
            tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open API)
        for k, v in tensors.items():
            if v.is_floating_point():
                tensors[k] = v + scale * torch.randn(v.shape, generator=gen, dtype=v.dtype)
        save_file(tensors, str(weights), metadata=meta)
    return dst


def png_bytes(seed: int, size: tuple[int, int] = (64, 96), fmt: str = "PNG") -> bytes:
    """A random RGB picture (H, W) = ``size`` encoded as ``fmt``."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    arr = rng.integers(0, 256, (*size, 3), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format=fmt)
    return buf.getvalue()


HIDDEN = 128


def build_tiny_qwen3vl(folder: Path) -> Path:
    """Save a tiny random Qwen3-VL (2 text + 2 vision layers, hidden 128) with an offline
    tokenizer and image processor to ``folder``."""
    import torch

    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import (
        PreTrainedTokenizerFast,
        Qwen3VLConfig,
        Qwen3VLForConditionalGeneration,
    )

    bpe = Tokenizer(models.BPE())
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    bpe.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=400,
        special_tokens=SPECIAL_TOKENS,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    bpe.train_from_iterator(CORPUS, trainer=trainer)
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=bpe,
        pad_token="<|endoftext|>",
        eos_token="<|im_end|>",
        additional_special_tokens=SPECIAL_TOKENS[1:],
    )
    ids = {t: bpe.token_to_id(t) for t in SPECIAL_TOKENS}
    config = Qwen3VLConfig(
        text_config={
            "vocab_size": bpe.get_vocab_size(),
            "hidden_size": HIDDEN,
            "intermediate_size": 256,
            "num_hidden_layers": 2,
            "num_attention_heads": 4,
            "num_key_value_heads": 2,
            "head_dim": 32,
            "max_position_embeddings": 1024,
            "pad_token_id": ids["<|endoftext|>"],
            "rope_parameters": {
                "rope_type": "default",
                "rope_theta": 10000.0,
                "mrope_section": [8, 4, 4],
                "mrope_interleaved": True,
            },
        },
        vision_config={
            "depth": 2,
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_heads": 4,
            "patch_size": 16,
            "spatial_merge_size": 2,
            "temporal_patch_size": 2,
            "out_hidden_size": HIDDEN,
            "num_position_embeddings": 64,
            "deepstack_visual_indexes": [0],
        },
        image_token_id=ids["<|image_pad|>"],
        video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"],
        vision_end_token_id=ids["<|vision_end|>"],
    )
    torch.manual_seed(0)
    model = Qwen3VLForConditionalGeneration(config).eval()
    model.save_pretrained(folder)
    tokenizer.save_pretrained(folder)
    # the released model's preprocessor_config.json, with a small pixel band
    preprocessor = {
        "size": {"longest_edge": 128 * 128, "shortest_edge": 64 * 64},
        "patch_size": 16,
        "temporal_patch_size": 2,
        "merge_size": 2,
        "image_mean": [0.5, 0.5, 0.5],
        "image_std": [0.5, 0.5, 0.5],
        "processor_class": "Qwen3VLProcessor",
        "image_processor_type": "Qwen2VLImageProcessorFast",
    }
    (folder / "preprocessor_config.json").write_text(json.dumps(preprocessor))
    return folder


CORPUS = [
    "holding a mug",
    "grasping a coffee mug",
    "the weather is rainy",
    "a soft sponge and a hard metal cup",
    DOCUMENT_INSTRUCTION,
    QUERY_INSTRUCTION,
    "system user assistant NULL",
]


SPECIAL_TOKENS = [
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
]
