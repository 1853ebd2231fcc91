"""Every grasp caption's embedding in a space (:func:`tactus_memory.touch.facets.grasp_captions`,
72 texts): a function of the space and the caption rule alone, so embedded in one batch once
per process and space and kept. The touch sense loads them when a server warms its senses
(``Sense.warm``, before ``ready``), so no write or search pays them; the write path keeps them
in the store (:mod:`tactus_memory.search.captions`) and the search path reads them from here
or from there."""

from __future__ import annotations

import contextlib
import threading
import weakref
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.touch.facets import grasp_captions
from tactus_memory.vectors import as_unit_rows

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space

#: space -> {grasp caption: its (D,) unit embedding}, kept while the space lives
_GRASP_VECTORS: weakref.WeakKeyDictionary[Any, dict[str, np.ndarray]] = weakref.WeakKeyDictionary()
_GRASP_LOCK = threading.Lock()


def grasp_caption_vectors(space: Space) -> dict[str, np.ndarray]:
    """Every grasp caption's (D,) unit embedding in ``space``: one batch on the first call for
    ``space``, then kept (a space that cannot be weakly referenced embeds them each call)."""
    with _GRASP_LOCK:
        try:
            got = _GRASP_VECTORS.get(space)
        except TypeError:  # a space that cannot be weakly referenced: embedded each time
            got = None
        if got is None:
            texts = grasp_captions()
            vecs = as_unit_rows(space.embed_texts(texts), space.dim, what="captions")
            got = dict(zip(texts, vecs, strict=True))
            with contextlib.suppress(TypeError):  # as above: kept where it can be
                _GRASP_VECTORS[space] = got
        return got
