"""The sense contract: how one kind of raw input becomes a vector in the memory's space.

Shape of the plug-in (after LanceDB's embedding registry): a name, a modality, ``dim``,
``embed`` for stored items (source side), ``query_transform`` for text queries compared
against this sense (query side), input validation, provenance, and lazy model loading.
The memory never branches on a sense's name; everything sense-specific lives in the sense.

The implementations live in ``tactus_memory.adapters``, one file each (text, image, vectors,
touch). Every sense class registers under a name (``@register("text")``,
:mod:`tactus_memory.senses.plugins`); ``config()`` is what a store records to rebuild it with
``create(space, **config)``.
"""

from __future__ import annotations

import io
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np

from tactus_memory.errors import (
    IdleWindowError,
    InvalidInputError,
    SenseConflictError,
)
from tactus_memory.spaces.base import Space
from tactus_memory.vectors import as_unit_rows


def array_to_bytes(arr: np.ndarray) -> bytes:
    """Store a small array losslessly (``.npy`` bytes) so a row can be re-embedded or drawn."""
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(arr), allow_pickle=False)
    return buf.getvalue()


def bytes_to_array(raw: bytes) -> np.ndarray:
    return np.load(io.BytesIO(raw), allow_pickle=False)


class Sense(ABC):
    """One sense registered in a memory."""

    #: unique name inside a memory, e.g. "text", "touch", "motion"
    name: str
    #: what kind of input: "text" | "touch" | "image" | "vector" | ...
    modality: str
    #: output dimension D (equals the space's dim)
    dim: int
    #: the space this sense maps into; None means "whatever space it is bound to"
    space_name: str | None = None
    #: (D,) vector removed from text queries compared with this sense (the touch
    #: sense's target centroid); None: text queries are compared as they are
    query_centroid: np.ndarray | None = None
    #: keyword options ``validate`` takes (``Memory.add(..., options=...)`` passes these on;
    #: e.g. the touch sense's ``calibrated``); options a sense does not declare are not its own
    validate_options: frozenset[str] = frozenset()
    #: what ``tactus_memory.senses.plugins.register`` files it under
    plugin_kind = "sense"
    #: ROS 2 message types a recording topic of this sense may carry (``from_message``)
    message_types: tuple[str, ...] = ()
    #: whether items are windows cut from a stream of frames: True exactly for a
    #: :class:`~tactus_memory.senses.windowed.WindowedSense` (touch: frames -> windows)
    windowed: bool = False

    def from_message(self, msg: Any, msgtype: str, where: str) -> Any:
        """One decoded ROS 2 message of a recording -> this sense's raw input (a windowed
        sense: one frame). ``where`` names the message in errors (RecordingError)."""
        raise InvalidInputError(f"{where}: sense {self.name!r} does not read recordings")

    @classmethod
    def create(cls, space: Space, /, **config: Any) -> Sense:
        """The sense from what a store recorded (``config()``), in the memory's ``space``."""
        return cls(space, **config)  # type: ignore[call-arg]

    def config(self) -> dict[str, Any]:
        """JSON keywords that rebuild this sense with :meth:`create` (recorded in the store)."""
        return {"name": self.name}

    def bind(self, space: Space) -> None:
        """Called by ``Memory.add_sense``. Raises ``SenseConflictError`` on a space mismatch."""
        if (self.space_name is not None and self.space_name != space.name) or (
            self.dim != space.dim
        ):
            raise SenseConflictError(
                f"sense {self.name!r} maps into space {self.space_name or 'any'!r} "
                f"(dimension {self.dim}), but this memory's space is {space.name!r} "
                f"(dimension {space.dim})"
            )

    def warm(self, space: Space) -> None:
        """Load now what this sense's first write or search in ``space`` would otherwise pay
        (derived embeddings, caches): a server calls it for every live sense before it answers
        ready (``tactus serve``, ``tactus mcp``). Default: nothing (models load in ``create``)."""
        return None

    @abstractmethod
    def validate(self, item: Any) -> Any:
        """Check one raw item and return its canonical form. Raises ``InvalidInputError``.
        A sense with ``validate_options`` takes them as keyword arguments."""

    def validate_many(
        self, items: Sequence[Any] | np.ndarray, *, skip_idle: bool = True, **options: Any
    ) -> tuple[list[Any], list[int]]:
        """N items -> (their canonical forms, the indices of those skipped as idle), the
        write path's one call per write. Each item as :meth:`validate` checks it; an item
        that raises :class:`~tactus_memory.errors.IdleWindowError` is skipped
        (``skip_idle``) or the error raised. A sense that can check a whole batch at once
        (the touch sense: one numpy pass over (B, K, 32, 32)) overrides it, with the same
        results and errors."""
        canon: list[Any] = []
        idle: list[int] = []
        for i, x in enumerate(items):
            try:
                canon.append(self.validate(x, **options))
            except IdleWindowError:
                if not skip_idle:
                    raise
                idle.append(i)
        return canon, idle

    @abstractmethod
    def embed(self, batch: Sequence[Any]) -> np.ndarray:
        """batch: N validated items (what ``validate`` returned; not checked again) ->
        (N, D) float32, L2-normalised."""

    def query_transform(self, queries: np.ndarray) -> np.ndarray:
        """queries: (N, D) text-query vectors -> (N, D) vectors comparable with this sense:
        normalize(q - query_centroid), the centring the sense's training targets had, or the
        queries as they are when the sense has no centroid. The registry stores the centroid,
        so a sense reopened from the store transforms queries exactly so."""
        if self.query_centroid is None:
            return queries
        q = np.asarray(queries, dtype=np.float32)
        return as_unit_rows(q - self.query_centroid[None, :], self.dim, what="query")

    def to_row(self, item: Any) -> dict[str, Any]:
        """Extra stored columns for one validated item: ``text`` and/or ``raw`` (npy bytes)."""
        return {}

    def from_row(self, row: dict[str, Any]) -> Any:
        """Rebuild the raw item from a stored row (for re-embedding and drawing)."""
        if row.get("raw") is not None:
            return bytes_to_array(row["raw"])
        return row.get("text")

    def provenance(self) -> dict[str, Any]:
        """Encoder name, version, checkpoint hash, calibration: what is needed to trust it."""
        return {"encoder": type(self).__name__}

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "modality": self.modality,
            "dim": self.dim,
            "space": self.space_name,
            "provenance": self.provenance(),
        }
