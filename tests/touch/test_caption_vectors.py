"""The grasp captions' embeddings (``touch/caption_vectors.py``): embedded in one batch the
first time a space asks, kept after; the touch sense's ``warm`` is that first time (the
server's side: tests/service/test_warm_senses.py)."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from tactus_memory.touch.caption_vectors import grasp_caption_vectors
from tactus_memory.touch.facets import grasp_captions


def counted(space: Any) -> tuple[Any, list[int]]:
    """A copy of ``space`` (a space of its own for the cache) that counts the texts each of
    its ``embed_texts`` calls embeds."""
    mine = copy.copy(space)
    calls: list[int] = []
    embed = space.embed_texts

    def embed_texts(texts, **kw):
        calls.append(len(texts))
        return embed(texts, **kw)

    mine.embed_texts = embed_texts
    return mine, calls


def test_the_touch_sense_warms_every_grasp_caption_once(enc, minilm_space) -> None:
    space, calls = counted(minilm_space)
    enc.warm(space)  # the real MiniLM, the touch sense's hook
    texts = grasp_captions()
    assert calls == [len(texts)]  # one batch of all of them
    again = grasp_caption_vectors(space)  # a touch write or a grasp search after it
    enc.warm(space)
    assert calls == [len(texts)]  # nothing embedded again
    assert list(again) == texts
    for text in (texts[0], texts[-1]):  # each the space's own embedding of its caption
        want = minilm_space.embed_texts([text])[0]
        assert np.allclose(again[text], want / np.linalg.norm(want), atol=1e-5), text
    other, other_calls = counted(minilm_space)
    grasp_caption_vectors(other)
    assert other_calls == [len(texts)]  # per space: another space embeds its own
