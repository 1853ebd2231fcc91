"""Qwen3-VL-Embedding-2B: one space for text and images, loaded from a LOCAL folder.

The recipe follows the Qwen3-VL-Embedding model card / reference embedder:

* each input becomes a ChatML conversation with a system instruction::

      <|im_start|>system\\n{instruction}<|im_end|>\\n
      <|im_start|>user\\n[<|vision_start|><|image_pad|>*n<|vision_end|>]{text}<|im_end|>\\n
      <|im_start|>assistant\\n

  queries use a retrieval instruction, documents (stored notes, images) use
  ``"Represent the user's input."``; an instruction without final punctuation gets a ``"."``;
* the final hidden state of ``Qwen3VLModel`` is pooled at the last attended token
  (:func:`last_token_pool`, correct under left or right padding);
* Matryoshka: keep the first ``dim`` coordinates, THEN L2-normalise
  (:func:`truncate_and_normalize`).

Tokenizer and image processor are used directly (no ``Qwen3VLProcessor``): the processor's
only job for images is to repeat ``<|image_pad|>`` ``grid_t*grid_h*grid_w / merge**2`` times,
which :func:`expand_image_tokens` does here, and building the processor requires torchvision
(its video processor), which this CPU environment does not have. Images are resized by the
PIL Qwen2-VL image processor (``smart_resize`` to multiples of patch*merge = 32, pixels
clamped to ``[min_pixels, max_pixels]``); the reference embedder resizes with qwen-vl-utils
to the same bounds and factor.

torch/transformers/PIL are imported lazily; constructing a space only reads ``config.json``.
"""

from __future__ import annotations

import inspect
import json
import os
import threading
import unicodedata
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import CapabilityError, InvalidInputError
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space, check_texts
from tactus_memory.vectors import as_unit_rows

QWEN3VL_NAME = "qwen3-vl-embedding-2b"
QWEN3VL_FULL_DIM = 2048
MIN_MATRYOSHKA_DIM = 64
QUERY_INSTRUCTION = "Retrieve images or text relevant to the user's query."
DOCUMENT_INSTRUCTION = "Represent the user's input."
MAX_LENGTH = 8192
IMAGE_FACTOR = 32  # patch_size 16 * spatial merge 2
MIN_PIXELS = 4 * IMAGE_FACTOR * IMAGE_FACTOR
MAX_PIXELS = 1800 * IMAGE_FACTOR * IMAGE_FACTOR

IM_START = "<|im_start|>"
IM_END = "<|im_end|>"
VISION_START = "<|vision_start|>"
VISION_END = "<|vision_end|>"
IMAGE_PAD = "<|image_pad|>"
PAD_TOKEN = "<|endoftext|>"


# -- small pure functions (unit-tested on hand-made tensors) ---------------------------------


def last_token_pool(hidden: Any, attention_mask: Any) -> Any:
    """hidden: (B, L, H), attention_mask: (B, L) 0/1 -> (B, H): each row's last attended token.

    Works for right padding (ones then zeros), left padding (zeros then ones) and a mix: the
    index is found from the mask itself, not from the batch's padding side.
    """
    import torch

    if hidden.ndim != 3 or attention_mask.ndim != 2 or hidden.shape[:2] != attention_mask.shape:
        raise InvalidInputError(
            f"hidden (B, L, H) and mask (B, L) disagree: {tuple(hidden.shape)} vs "
            f"{tuple(attention_mask.shape)}"
        )
    mask = attention_mask.to(torch.long)
    if (mask.sum(dim=1) == 0).any():
        raise InvalidInputError("a row of the attention mask is all zero; it has no last token")
    length = mask.shape[1]
    last = length - 1 - mask.flip(dims=[1]).argmax(dim=1)
    rows = torch.arange(hidden.shape[0], device=hidden.device)
    return hidden[rows, last.to(hidden.device)]


def truncate_and_normalize(x: np.ndarray, dim: int) -> np.ndarray:
    """Matryoshka readout. x: (N, H) -> (N, dim) float32: first ``dim`` coords, then L2 norm."""
    arr = np.asarray(x, dtype=np.float32)
    if arr.ndim != 2:
        raise InvalidInputError(f"embeddings must be (N, H), got {arr.shape}")
    if not 0 < dim <= arr.shape[1]:
        raise InvalidInputError(f"cannot truncate {arr.shape[1]}-d embeddings to {dim}")
    if arr.shape[0] == 0:
        return np.zeros((0, dim), dtype=np.float32)
    return as_unit_rows(arr[:, :dim], dim, what="Qwen3-VL embedding")


def normalize_instruction(instruction: str) -> str:
    """Strip, and end with punctuation as the reference embedder does (adds ``"."``)."""
    text = instruction.strip()
    if text and not unicodedata.category(text[-1]).startswith("P"):
        text += "."
    return text


def build_prompt(instruction: str, text: str | None = None, *, image: bool = False) -> str:
    """One ChatML prompt; an image is a single ``<|image_pad|>`` placeholder (expanded later)."""
    user = ""
    if image:
        user += VISION_START + IMAGE_PAD + VISION_END
    if text:
        user += text
    if not user:
        user = "NULL"  # the reference embedder's stand-in for empty input
    return (
        f"{IM_START}system\n{normalize_instruction(instruction)}{IM_END}\n"
        f"{IM_START}user\n{user}{IM_END}\n"
        f"{IM_START}assistant\n"
    )


def expand_image_tokens(prompt: str, n_tokens: int) -> str:
    """Replace the one ``<|image_pad|>`` placeholder of ``prompt`` by ``n_tokens`` copies."""
    if prompt.count(IMAGE_PAD) != 1:
        raise InvalidInputError("prompt must hold exactly one image placeholder")
    return prompt.replace(IMAGE_PAD, IMAGE_PAD * int(n_tokens))


def _read_hidden_size(path: Path) -> int:
    cfg = json.loads((path / "config.json").read_text())
    text_cfg = cfg.get("text_config") or {}
    size = text_cfg.get("hidden_size", cfg.get("hidden_size"))
    if not isinstance(size, int):
        raise InvalidInputError(f"{path / 'config.json'} has no text_config.hidden_size")
    return size


# -- the space ---------------------------------------------------------------------------------


@register("qwen3vl", "qwen3-vl-embedding-2b")
class Qwen3VLSpace(Space):
    """Qwen3-VL-Embedding-2B from a local folder; text and image embeddings in one space.

    path: local model folder (config.json, safetensors, tokenizer, preprocessor_config.json).
    dim: Matryoshka output size, ``64 <= dim <= hidden size`` (2048 for the 2B model);
        ``None`` means the full size. The store name carries it: ``qwen3-vl-embedding-2b@512``.
    instruction: query-side instruction; ``document_instruction`` is the document side.
    device / dtype: torch device and dtype (default float32 on CPU, bfloat16 on CUDA).
    """

    has_vision = True
    needs_path = True

    @classmethod
    def create(cls, path: str | None = None, dim: int | None = None) -> Qwen3VLSpace:
        if path is None:
            raise ValueError(
                "space 'qwen3-vl-embedding-2b' needs path= a local Qwen3-VL-Embedding-2B folder"
            )
        return cls(path, dim=dim)  # None: the model's full size (2048 for the 2B)

    def __init__(
        self,
        path: str | os.PathLike[str],
        dim: int | None = None,
        instruction: str = QUERY_INSTRUCTION,
        device: str = "cpu",
        *,
        document_instruction: str = DOCUMENT_INSTRUCTION,
        dtype: str | None = None,
        batch_size: int = 8,
        max_length: int = MAX_LENGTH,
        min_pixels: int = MIN_PIXELS,
        max_pixels: int = MAX_PIXELS,
    ) -> None:
        self.path = Path(path).expanduser()
        if not self.path.is_dir():
            raise FileNotFoundError(
                f"Qwen3-VL-Embedding folder not found: {str(path)!r}. Pass a local folder holding "
                "config.json, the safetensors weights and the tokenizer (hub ids are never "
                "downloaded; fetch the model beforehand, e.g. `hf download "
                "Qwen/Qwen3-VL-Embedding-2B --local-dir <folder>`)."
            )
        if not (self.path / "config.json").is_file():
            raise FileNotFoundError(f"{self.path} has no config.json; it is not a model folder")
        self.full_dim = _read_hidden_size(self.path)
        if dim is None:
            dim = self.full_dim
        if isinstance(dim, bool) or not isinstance(dim, int):
            raise InvalidInputError(f"dim must be an int, got {dim!r}")
        if not MIN_MATRYOSHKA_DIM <= dim <= self.full_dim:
            raise InvalidInputError(
                f"dim {dim} out of range: Matryoshka dims run {MIN_MATRYOSHKA_DIM}..{self.full_dim}"
            )
        self.dim = dim
        self.name = QWEN3VL_NAME if dim == self.full_dim else f"{QWEN3VL_NAME}@{dim}"
        if not instruction.strip() or not document_instruction.strip():
            raise InvalidInputError("instructions must be non-empty")
        self.instruction = instruction
        self.document_instruction = document_instruction
        self.device = device
        self.dtype = dtype
        self.batch_size = int(batch_size)
        self.max_length = int(max_length)
        self.min_pixels = int(min_pixels)
        self.max_pixels = int(max_pixels)
        self._model: Any = None
        self._tokenizer: Any = None
        self._image_processor: Any = None
        self._passes_mm_types = False
        self._fingerprint: str | None = None
        self._lock = threading.Lock()
        # one encode at a time: fast tokenizers are not safe under concurrent calls
        self._encode_lock = threading.Lock()

    # -- loading -----------------------------------------------------------------------------

    def _load(self) -> None:
        if self._model is not None:
            return
        with self._lock:
            if self._model is not None:
                return
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            import torch
            from transformers import AutoTokenizer, Qwen3VLModel

            tokenizer = AutoTokenizer.from_pretrained(str(self.path), local_files_only=True)
            for tok in (IM_START, IM_END, VISION_START, VISION_END, IMAGE_PAD):
                if tokenizer.convert_tokens_to_ids(tok) in (None, tokenizer.unk_token_id):
                    raise InvalidInputError(f"tokenizer at {self.path} lacks the token {tok}")
            image_processor = None
            if (self.path / "preprocessor_config.json").is_file():
                from transformers import Qwen2VLImageProcessorPil

                image_processor = Qwen2VLImageProcessorPil.from_pretrained(
                    str(self.path), local_files_only=True
                )
            if self.dtype is not None:
                torch_dtype = getattr(torch, self.dtype)
            else:
                on_cuda = str(self.device).startswith("cuda")
                torch_dtype = torch.bfloat16 if on_cuda else torch.float32
            model = Qwen3VLModel.from_pretrained(
                str(self.path), dtype=torch_dtype, local_files_only=True
            )
            model.to(self.device)
            model.eval()
            hidden = model.config.text_config.hidden_size
            if hidden != self.full_dim:
                raise InvalidInputError(f"model hidden size {hidden} != config {self.full_dim}")
            params = inspect.signature(model.forward).parameters
            self._passes_mm_types = "mm_token_type_ids" in params
            self._tokenizer = tokenizer
            self._image_processor = image_processor
            self._model = model

    @property
    def loaded(self) -> bool:
        return self._model is not None

    def fingerprint(self) -> str:
        """sha256 prefix over config.json and the weight files' sizes and ends (cached)."""
        if self._fingerprint is None:
            from tactus_memory.spaces.fingerprint import model_fingerprint

            self._fingerprint = model_fingerprint(self.path)
        return self._fingerprint

    # -- encoding ----------------------------------------------------------------------------

    def _tokenize(self, prompts: list[str], texts: list[str | None]) -> tuple[Any, Any]:
        """prompts: B strings -> input_ids (B, L) long, attention_mask (B, L) long, right-padded.

        ``texts[i]`` is the user text inside ``prompts[i]`` (None for images). A prompt longer
        than ``max_length`` tokens keeps its chat scaffold and loses the tail of its user text,
        so it still ends with ``<|im_end|>\n<|im_start|>assistant\n`` (the pooled token).
        """
        import torch

        tok = self._tokenizer
        rows: list[list[int]] = []
        for prompt, text in zip(prompts, texts, strict=True):
            ids = tok(prompt, add_special_tokens=False)["input_ids"]
            if len(ids) > self.max_length and text:
                head, _, tail = prompt.rpartition(text)
                head_ids = tok(head, add_special_tokens=False)["input_ids"]
                tail_ids = tok(tail, add_special_tokens=False)["input_ids"]
                budget = max(self.max_length - len(head_ids) - len(tail_ids), 0)
                text_ids = tok(text, add_special_tokens=False)["input_ids"][:budget]
                ids = head_ids + text_ids + tail_ids
            rows.append(ids)
        pad_id = tok.pad_token_id
        if pad_id is None:
            pad_id = tok.convert_tokens_to_ids(PAD_TOKEN)
        longest = max(len(r) for r in rows)
        input_ids = torch.full((len(rows), longest), int(pad_id), dtype=torch.long)
        mask = torch.zeros((len(rows), longest), dtype=torch.long)
        for i, r in enumerate(rows):
            input_ids[i, : len(r)] = torch.tensor(r, dtype=torch.long)
            mask[i, : len(r)] = 1
        return input_ids, mask

    def _forward(self, input_ids: Any, mask: Any, **vision: Any) -> np.ndarray:
        """-> (B, H) float32 numpy: last-token-pooled final hidden states (not normalised)."""
        import torch

        model = self._model
        kwargs: dict[str, Any] = {"input_ids": input_ids.to(self.device)}
        kwargs["attention_mask"] = mask.to(self.device)
        if vision:
            image_id = self._tokenizer.convert_tokens_to_ids(IMAGE_PAD)
            kwargs["pixel_values"] = vision["pixel_values"].to(self.device, model.dtype)
            kwargs["image_grid_thw"] = vision["image_grid_thw"].to(self.device)
            if self._passes_mm_types:
                kwargs["mm_token_type_ids"] = (input_ids == image_id).to(torch.int).to(self.device)
        with torch.inference_mode():
            out = model(**kwargs, use_cache=False)
            pooled = last_token_pool(out.last_hidden_state, kwargs["attention_mask"])
        return pooled.float().cpu().numpy()

    def embed_texts(self, texts: Sequence[str], *, query: bool = False) -> np.ndarray:
        """texts: N strings -> (N, dim) float32, unit rows. Query vs document instruction."""
        items = check_texts(texts)
        if not items:
            return np.zeros((0, self.dim), dtype=np.float32)
        self._load()
        instruction = self.instruction if query else self.document_instruction
        chunks = []
        for start in range(0, len(items), self.batch_size):
            batch = items[start : start + self.batch_size]
            prompts = [build_prompt(instruction, t) for t in batch]
            with self._encode_lock:
                input_ids, mask = self._tokenize(prompts, list(batch))
                chunks.append(self._forward(input_ids, mask))
        return truncate_and_normalize(np.concatenate(chunks, axis=0), self.dim)

    def embed_images(self, images: Sequence[Any]) -> np.ndarray:
        """images: N PIL images or (H, W, 3) uint8 arrays -> (N, dim) float32, unit rows.

        Each image is embedded on the document side (``document_instruction``), alone.
        """
        pil_images = [_to_pil(img) for img in images]
        if not pil_images:
            return np.zeros((0, self.dim), dtype=np.float32)
        self._load()
        if self._image_processor is None:
            raise CapabilityError(f"{self.path} has no preprocessor_config.json: no image path")
        merge = int(self._image_processor.merge_size)
        size = {"shortest_edge": self.min_pixels, "longest_edge": self.max_pixels}
        chunks = []
        for start in range(0, len(pil_images), self.batch_size):
            batch = pil_images[start : start + self.batch_size]
            vision = self._image_processor(images=batch, size=size, return_tensors="pt")
            grid = vision["image_grid_thw"]  # (B, 3) long: t, h, w in patches
            # pixel_values: (sum_i t*h*w, 3*temporal_patch*patch*patch) float32
            prompt = build_prompt(self.document_instruction, image=True)
            prompts = [expand_image_tokens(prompt, int(g.prod()) // merge**2) for g in grid]
            with self._encode_lock:
                input_ids, mask = self._tokenize(prompts, [None] * len(prompts))
                pooled = self._forward(
                    input_ids, mask, pixel_values=vision["pixel_values"], image_grid_thw=grid
                )
            chunks.append(pooled)
        return truncate_and_normalize(np.concatenate(chunks, axis=0), self.dim)

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info.update(
            {
                "model": "Qwen3-VL-Embedding-2B",
                "full_dim": self.full_dim,
                "fingerprint": self.fingerprint(),
                "query_instruction": normalize_instruction(self.instruction),
                "document_instruction": normalize_instruction(self.document_instruction),
            }
        )
        return info


def _to_pil(image: Any) -> Any:
    """PIL image or (H, W, 3) uint8 array -> RGB PIL image."""
    from PIL import Image

    if isinstance(image, Image.Image):
        return image.convert("RGB")
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise InvalidInputError(
            f"image must be PIL or (H, W, 3) uint8, got {arr.shape} {arr.dtype}"
        )
    return Image.fromarray(np.ascontiguousarray(arr)).convert("RGB")
