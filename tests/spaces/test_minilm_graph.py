"""MiniLM's ONNX graph written without torch (:mod:`tactus_memory.export.minilm_graph`) gives
sentence-transformers' vectors, and the shipped reference vectors (what a server without torch
checks its export against) are sentence-transformers' too."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactus_memory.export.cache import CHECK_TEXTS, TOLERANCE, reference_vectors
from tactus_memory.export.minilm_graph import write_minilm
from tactus_memory.spaces.minilm import MiniLMSpace
from tactus_memory.spaces.onnx_runtime import OnnxMiniLM

pytestmark = pytest.mark.slow


def test_the_torch_free_graph_gives_sentence_transformers_vectors(tmp_path: Path) -> None:
    texts = [*CHECK_TEXTS, "", "a much longer sentence " * 60]  # empty, and one truncated at 256
    want = MiniLMSpace(cache_size=0).embed_texts(texts)
    got = OnnxMiniLM(write_minilm(tmp_path)).embed_texts(texts)
    assert got.shape == want.shape == (len(texts), 384)
    assert float(np.abs(got - want).max()) < TOLERANCE
    ref_texts, ref = reference_vectors()
    assert ref_texts == CHECK_TEXTS
    assert float(np.abs(ref - want[: len(CHECK_TEXTS)]).max()) < TOLERANCE
