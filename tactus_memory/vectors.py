"""The one readout: every vector that enters or leaves the memory passes through here."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import DimensionMismatchError, InvalidInputError

if TYPE_CHECKING:
    import pyarrow as pa

EPS = 1e-12
#: largest absolute vector component: the float32 norm of 65536 of them stays finite
MAX_COMPONENT = 1e15


def as_unit_rows(
    x: np.ndarray | Sequence[float] | list[Any], dim: int | None = None, *, what: str = "vector"
) -> np.ndarray:
    """Validate and L2-normalise vectors.

    x: (D,) or (N, D) numbers  ->  (N, D) float32, each row of unit norm.
    Raises ``DimensionMismatchError`` when D != dim and ``InvalidInputError`` on NaN/inf,
    ragged input or all-zero rows.
    """
    try:
        arr = np.asarray(x, dtype=np.float32)
    except (ValueError, TypeError) as exc:
        raise InvalidInputError(
            f"{what} is not a numeric array (ragged or non-numeric): {exc}"
        ) from exc
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise InvalidInputError(f"{what} must have shape (D,) or (N, D), got {arr.shape}")
    if dim is not None and arr.shape[1] != dim:
        raise DimensionMismatchError(f"{what} has dimension {arr.shape[1]}, expected {dim}")
    if not np.isfinite(arr).all():
        raise InvalidInputError(f"{what} contains NaN or inf")
    if arr.size and float(np.abs(arr).max()) > MAX_COMPONENT:
        raise InvalidInputError(
            f"{what} has components beyond +-{MAX_COMPONENT:g} (its norm would overflow)"
        )
    norms = np.linalg.norm(arr, axis=1, keepdims=True)
    if (norms < EPS).any():
        raise InvalidInputError(f"{what} has an all-zero row; it has no direction")
    return (arr / norms).astype(np.float32)


def vector_rows(column: pa.Array | pa.ChunkedArray, dim: int) -> np.ndarray:
    """A fixed-size-list vector column (N x width) -> (N, dim) float32: the embeddings as
    stored, without the sense codes a store may keep after them (width - dim columns)."""
    import pyarrow as pa

    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    width = column.type.list_size
    if width < dim:
        raise DimensionMismatchError(f"stored vectors have dimension {width}, expected {dim}")
    return np.asarray(column.flatten(), dtype=np.float32).reshape(-1, width)[:, :dim]


def vector_column(tbl: pa.Table, dim: int) -> np.ndarray:
    """A scanned table's ``vector`` column -> (N, dim) float32 (:func:`vector_rows`)."""
    return vector_rows(tbl.column("vector"), dim)
