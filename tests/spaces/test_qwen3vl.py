"""Qwen3VLSpace on a tiny randomly-initialised Qwen3-VL built here and saved to tmp_path.

The real 2B weights are not available offline; the tiny model exercises the same code path
(transformers' Qwen3VLModel, a byte-level BPE tokenizer with the Qwen special tokens, the PIL
Qwen2-VL image processor). Pooling and Matryoshka normalisation are also tested on hand-made
tensors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.qwen_tiny import HIDDEN, build_tiny_qwen3vl

pytest.importorskip("transformers")

from tactus_memory.adapters.image import ImageSense  # noqa: E402
from tactus_memory.adapters.text import TextSense  # noqa: E402
from tactus_memory.errors import CapabilityError, InvalidInputError  # noqa: E402
from tactus_memory.spaces import get_space  # noqa: E402
from tactus_memory.spaces.qwen3vl import (  # noqa: E402
    DOCUMENT_INSTRUCTION,
    IMAGE_PAD,
    QUERY_INSTRUCTION,
    Qwen3VLSpace,
    build_prompt,
    expand_image_tokens,
    last_token_pool,
    normalize_instruction,
    truncate_and_normalize,
)


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_qwen3vl(tmp_path_factory.mktemp("tiny-qwen3vl"))


@pytest.fixture(scope="module")
def tiny_space(tiny_dir: Path) -> Qwen3VLSpace:
    return Qwen3VLSpace(tiny_dir, max_pixels=128 * 128)


# -- pure functions ----------------------------------------------------------------------------


def test_last_token_pool_right_padding() -> None:
    hidden = torch.arange(2 * 4 * 3, dtype=torch.float32).reshape(2, 4, 3)
    mask = torch.tensor([[1, 1, 1, 0], [1, 1, 0, 0]])
    pooled = last_token_pool(hidden, mask)
    assert torch.equal(pooled[0], hidden[0, 2])
    assert torch.equal(pooled[1], hidden[1, 1])


def test_last_token_pool_left_padding_and_full_rows() -> None:
    hidden = torch.randn(3, 5, 4)
    mask = torch.tensor([[0, 0, 1, 1, 1], [1, 1, 1, 1, 1], [0, 0, 0, 0, 1]])
    pooled = last_token_pool(hidden, mask)
    for i in range(3):
        assert torch.equal(pooled[i], hidden[i, 4])


def test_last_token_pool_rejects_empty_row_and_bad_shapes() -> None:
    with pytest.raises(InvalidInputError):
        last_token_pool(torch.zeros(2, 3, 4), torch.tensor([[1, 0, 0], [0, 0, 0]]))
    with pytest.raises(InvalidInputError):
        last_token_pool(torch.zeros(2, 3, 4), torch.ones(2, 4))


def test_truncate_then_normalize() -> None:
    x = np.array([[3.0, 4.0, 100.0, -7.0], [0.0, 2.0, 1.0, 1.0]], dtype=np.float32)
    out = truncate_and_normalize(x, 2)
    assert out.shape == (2, 2) and out.dtype == np.float32
    np.testing.assert_allclose(out, [[0.6, 0.8], [0.0, 1.0]], atol=1e-6)
    # truncating after normalising the full vector would give a shorter, non-unit row
    full = x[0] / np.linalg.norm(x[0])
    assert np.linalg.norm(full[:2]) < 0.1
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-6)
    assert truncate_and_normalize(np.zeros((0, 8)), 4).shape == (0, 4)
    with pytest.raises(InvalidInputError):
        truncate_and_normalize(x, 5)


def test_prompt_format() -> None:
    prompt = build_prompt("Find the touch", "a mug")
    assert prompt == (
        "<|im_start|>system\nFind the touch.<|im_end|>\n"
        "<|im_start|>user\na mug<|im_end|>\n<|im_start|>assistant\n"
    )
    assert normalize_instruction(QUERY_INSTRUCTION) == QUERY_INSTRUCTION
    image_prompt = build_prompt(DOCUMENT_INSTRUCTION, image=True)
    assert "<|vision_start|><|image_pad|><|vision_end|><|im_end|>" in image_prompt
    assert expand_image_tokens(image_prompt, 6).count(IMAGE_PAD) == 6
    assert "user\nNULL<|im_end|>" in build_prompt(DOCUMENT_INSTRUCTION, "")


# -- construction ------------------------------------------------------------------------------


def test_missing_folder_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not found"):
        Qwen3VLSpace(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="hub ids are never"):
        Qwen3VLSpace("Qwen/Qwen3-VL-Embedding-2B")
    with pytest.raises(FileNotFoundError, match="config.json"):
        Qwen3VLSpace(tmp_path)


def test_name_dim_and_vision(tiny_dir: Path) -> None:
    full = Qwen3VLSpace(tiny_dir)
    assert (full.name, full.dim, full.has_vision) == ("qwen3-vl-embedding-2b", HIDDEN, True)
    assert not full.loaded  # constructing reads config.json only
    small = Qwen3VLSpace(tiny_dir, dim=64)
    assert (small.name, small.dim) == ("qwen3-vl-embedding-2b@64", 64)
    for bad in (32, HIDDEN + 1, 64.0):
        with pytest.raises(InvalidInputError):
            Qwen3VLSpace(tiny_dir, dim=bad)  # type: ignore[arg-type]


def test_registry_builds_qwen(tiny_dir: Path) -> None:
    space = get_space("qwen3vl", path=str(tiny_dir), dim=64)
    assert isinstance(space, Qwen3VLSpace) and space.dim == 64
    assert get_space("qwen3-vl-embedding-2b@64", path=str(tiny_dir)).name.endswith("@64")
    with pytest.raises(ValueError, match="path"):
        get_space("qwen3vl")


# -- the real code path on the tiny model ------------------------------------------------------


def test_text_embeddings_shape_norm_deterministic(tiny_space: Qwen3VLSpace) -> None:
    texts = ["holding a mug", "the weather is rainy", "a soft sponge"]
    a = tiny_space.embed_texts(texts)
    assert a.shape == (3, HIDDEN) and a.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-5)
    b = tiny_space.embed_texts(texts)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[0], a[1])
    assert tiny_space.embed_texts([]).shape == (0, HIDDEN)


def test_batching_and_padding_do_not_change_vectors(tiny_dir: Path) -> None:
    """A short text padded inside a batch gets the same vector as alone (mask-aware pooling)."""
    space = Qwen3VLSpace(tiny_dir, batch_size=4)
    batch = space.embed_texts(["holding a mug", "a much longer sentence about the rainy weather"])
    alone = space.embed_texts(["holding a mug"])
    np.testing.assert_allclose(batch[0], alone[0], atol=1e-4)


def test_long_text_is_truncated_keeping_the_scaffold(tiny_dir: Path) -> None:
    space = Qwen3VLSpace(tiny_dir, max_length=48)
    long_text = "holding a mug " * 200
    out = space.embed_texts([long_text, "a mug"])
    assert out.shape == (2, HIDDEN)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    prompt = build_prompt(DOCUMENT_INSTRUCTION, long_text)
    ids, mask = space._tokenize([prompt], [long_text])
    assert ids.shape[1] == 48 and int(mask.sum()) == 48
    suffix = space._tokenizer("<|im_end|>\n<|im_start|>assistant\n", add_special_tokens=False)
    tail = suffix["input_ids"]
    assert ids[0, -len(tail) :].tolist() == tail


def test_query_and_document_instructions_differ(tiny_space: Qwen3VLSpace) -> None:
    q = tiny_space.embed_texts(["holding a mug"], query=True)
    d = tiny_space.embed_texts(["holding a mug"], query=False)
    assert not np.allclose(q, d, atol=1e-4)


def test_matryoshka_space_is_prefix_of_full(tiny_dir: Path, tiny_space: Qwen3VLSpace) -> None:
    small = Qwen3VLSpace(tiny_dir, dim=64)
    full = tiny_space.embed_texts(["grasping a coffee mug"])
    part = small.embed_texts(["grasping a coffee mug"])
    assert part.shape == (1, 64)
    np.testing.assert_allclose(np.linalg.norm(part, axis=1), 1.0, atol=1e-5)
    expected = full[:, :64] / np.linalg.norm(full[:, :64], axis=1, keepdims=True)
    np.testing.assert_allclose(part, expected, atol=1e-5)


def test_image_embeddings(tiny_space: Qwen3VLSpace) -> None:
    from PIL import Image

    rng = np.random.default_rng(0)
    arr = rng.integers(0, 256, (48, 80, 3), dtype=np.uint8)
    other = rng.integers(0, 256, (96, 64, 3), dtype=np.uint8)
    out = tiny_space.embed_images([arr, Image.fromarray(other)])
    assert out.shape == (2, HIDDEN) and out.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    assert not np.allclose(out[0], out[1], atol=1e-4)
    same_size = tiny_space.embed_images([arr, 255 - arr])  # same grid, other pixels
    assert not np.allclose(same_size[0], same_size[1], atol=1e-4)
    # the folder's preprocessor config is honoured (0.5 mean/std, patch 16, merge 2)
    assert list(tiny_space._image_processor.image_mean) == [0.5, 0.5, 0.5]
    assert tiny_space._image_processor.patch_size == 16
    again = tiny_space.embed_images([Image.fromarray(arr)])
    np.testing.assert_allclose(again[0], out[0], atol=1e-4)
    text = tiny_space.embed_texts(["holding a mug"])
    assert not np.allclose(text[0], out[0], atol=1e-3)
    with pytest.raises(InvalidInputError):
        tiny_space.embed_images([np.zeros((8, 8), dtype=np.uint8)])
    assert tiny_space.embed_images([]).shape == (0, HIDDEN)


def test_senses_work_through_the_space(tiny_space: Qwen3VLSpace) -> None:
    text = TextSense(tiny_space)
    image = ImageSense(tiny_space)
    assert text.dim == image.dim == HIDDEN
    assert text.embed(["holding a mug"]).shape == (1, HIDDEN)
    frame = np.full((64, 64, 3), 128, dtype=np.uint8)
    assert image.embed([image.validate(frame)]).shape == (1, HIDDEN)


def test_no_preprocessor_means_no_image_path(tiny_dir: Path, tmp_path: Path) -> None:
    import shutil

    copy = tmp_path / "text-only"
    shutil.copytree(tiny_dir, copy)
    (copy / "preprocessor_config.json").unlink()
    space = Qwen3VLSpace(copy)
    assert space.embed_texts(["holding a mug"]).shape == (1, HIDDEN)
    with pytest.raises(CapabilityError):
        space.embed_images([np.zeros((64, 64, 3), dtype=np.uint8)])


def test_saved_config_is_qwen3_vl(tiny_dir: Path) -> None:
    cfg = json.loads((tiny_dir / "config.json").read_text())
    assert cfg["model_type"] == "qwen3_vl"


def test_concurrent_first_use_and_custom_instruction(tiny_dir: Path) -> None:
    import threading

    space = Qwen3VLSpace(tiny_dir, instruction="Find the touch that matches")
    results: list[np.ndarray] = []

    def work() -> None:
        results.append(space.embed_texts(["holding a mug"], query=True))

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 3
    for r in results[1:]:
        np.testing.assert_allclose(r, results[0], atol=1e-5)
    default = Qwen3VLSpace(tiny_dir).embed_texts(["holding a mug"], query=True)
    assert not np.allclose(default, results[0], atol=1e-4)
    assert space.describe()["query_instruction"] == "Find the touch that matches."
