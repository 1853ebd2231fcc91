"""Sense codes: a few dimensions after each stored vector that set each sense's rows apart
in the ANN index, without changing any ranking.

Why: a text question is near the notes and far from every touch window (calibrated cosine
means 0.163 against -0.021), so in one IVF index over all senses the partitions nearest a
question hold notes, and a search within a touch sense had to probe past all of them (256 of
976 partitions at 1M rows) to reach its own best rows. Each stored row ``v`` (unit, D) is kept
as ``[v, CODE_WEIGHT * c(sense)]`` (D + ``CODE_DIMS``), ``c`` a unit vector of signs drawn
from the sense's name. Rows of different senses are then far apart, k-means gives each sense
partitions of its own, and a query within sense ``s`` asks ``[q, CODE_WEIGHT * c(s)]``: its
nearest partitions are ``s``'s (a touch sense reaches recall@10 0.99 at 8 probes;
benchmarks/search_1m.py, docs/operations/speed.md).

Nothing ranks differently: every row and query part has norm 1, so within one sense the
code adds the same ``CODE_WEIGHT**2`` to every dot product, and a query without a code
(``[q, 0]``, several senses at once) scales every cosine by the same factor. The cosine of
the embeddings is recovered exactly from the coded distance (:func:`embedding_distance`),
and every read hands back the D embedding columns only (:func:`strip_table`). A store records
its codes in the vector field's metadata (``FIELD_KEY``); a store made before has none and
is read and searched as it always was.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from tactus_memory.vectors import vector_rows

if TYPE_CHECKING:
    import pyarrow as pa

#: dimensions of a sense code: sign vectors of 16 bits, so two senses' codes agree in 8 of
#: 16 signs on average (dot product 0, standard deviation 0.25; identical for 1 pair in 65,536)
CODE_DIMS = 16
#: norm of the code against the unit embedding: rows of two senses with orthogonal codes are
#: sqrt(2) apart in the code alone, farther than any two unit embeddings' typical distance;
#: measured at 1M rows: touch recall@10 0.99 at 8 probes, notes 0.98 at 8 (CODE_DIMS 16)
CODE_WEIGHT = 1.0
#: the vector field's metadata key holding how many code dimensions its rows carry
FIELD_KEY = b"tactus.sense_codes"


@functools.lru_cache(maxsize=256)
def code(sense: str, dims: int = CODE_DIMS) -> np.ndarray:
    """(dims,) float32 unit sign vector of ``sense``: the first ``dims`` bits of the sha256
    of its name as +-1/sqrt(dims)."""
    digest = hashlib.sha256(sense.encode()).digest()
    bits = np.unpackbits(np.frombuffer(digest, np.uint8))[:dims]
    out = (bits.astype(np.float32) * 2.0 - 1.0) / np.sqrt(dims, dtype=np.float32)
    out.setflags(write=False)
    return out


def codes_of(field: pa.Field) -> int:
    """How many code dimensions a vector field's rows carry (0: a store made before)."""
    meta = field.metadata or {}
    return int(meta.get(FIELD_KEY, b"0"))


def with_code(vectors: np.ndarray, sense: str, dims: int) -> np.ndarray:
    """(N, D) rows of ``sense`` -> (N, D + dims) as stored: each row's code scaled by its own
    norm (unit rows: by 1), so a row's cosine to a coded query never depends on its norm."""
    vectors = np.asarray(vectors, np.float32)
    if not dims:
        return vectors
    norms = np.linalg.norm(vectors, axis=1, keepdims=True)
    return np.concatenate([vectors, norms * (CODE_WEIGHT * code(sense, dims))], axis=1)


def with_codes(vectors: np.ndarray, senses: np.ndarray, dims: int) -> np.ndarray:
    """(N, D) rows of several senses (``senses``: each row's sense name) -> (N, D + dims)
    as stored, each row as :func:`with_code` stores it for its own sense: a store made
    before codes, moved over (:mod:`tactus_memory.storage.migrate`)."""
    vectors = np.asarray(vectors, np.float32)
    names, which = np.unique(np.asarray(senses, dtype=object), return_inverse=True)
    which = which.reshape(-1)
    out = np.empty((len(vectors), vectors.shape[1] + dims), np.float32)
    for n, name in enumerate(names):
        rows = which == n
        out[rows] = with_code(vectors[rows], str(name), dims)
    return out


def coded_query(q: np.ndarray, sense: str | None, dims: int) -> np.ndarray:
    """(D,) unit query -> (D + dims,): with ``sense``'s code (a search within that sense
    only), or zeros (several senses: every cosine scaled alike)."""
    q = np.asarray(q, np.float32).reshape(-1)
    if not dims:
        return q
    tail = CODE_WEIGHT * code(sense, dims) if sense is not None else np.zeros(dims, np.float32)
    return np.concatenate([q, tail])


def embedding_distance(distance: np.ndarray, coded: bool) -> np.ndarray:
    """Cosine distances to stored rows (unit embedding and code) -> 1 - cosine of the
    embeddings alone. A query with the rows' own code (``coded``): cos' = (cos + w^2) /
    (1 + w^2); without a code: cos' = cos / sqrt(1 + w^2)."""
    d = np.asarray(distance, np.float64)
    w2 = CODE_WEIGHT**2
    if coded:
        return (1.0 + w2) * d
    return 1.0 - np.sqrt(1.0 + w2) * (1.0 - d)


def vector_array(vectors: np.ndarray, sense: str, width: int) -> pa.FixedSizeListArray:
    """(N, D) rows of ``sense`` -> the stored column of a vector field ``width`` wide (D, or
    D + its codes)."""
    import pyarrow as pa

    vectors = np.asarray(vectors, np.float32)
    stored = with_code(vectors, sense, width - vectors.shape[1])
    return pa.FixedSizeListArray.from_arrays(pa.array(stored.reshape(-1), pa.float32()), width)


def strip_column(column: pa.ChunkedArray | pa.Array, dim: int) -> pa.FixedSizeListArray:
    """A stored vector column (N x (D + codes)) -> its (N x D) embeddings."""
    import pyarrow as pa

    flat = vector_rows(column, dim)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1), pa.float32()), dim)


def strip_table(tbl: pa.Table, dim: int) -> pa.Table:
    """``tbl`` with its ``vector`` column (if any, and if coded) cut to the D embedding
    columns."""
    import pyarrow as pa

    at = tbl.schema.get_field_index("vector")
    if at < 0 or tbl.schema.field(at).type.list_size == dim:
        return tbl
    field = pa.field("vector", pa.list_(pa.float32(), dim), nullable=False)
    return tbl.set_column(at, field, strip_column(tbl.column(at), dim))


def code_batches(
    batches: Iterable[pa.RecordBatch], sense: str, field: pa.Field
) -> Iterator[pa.RecordBatch]:
    """Batches with a (N x D) ``vector`` column, all of ``sense`` -> the same batches with
    their vectors as ``field`` stores them (a re-embedding's staged vectors, swapped in)."""
    width = field.type.list_size
    for batch in batches:
        at = batch.schema.get_field_index("vector")
        col = batch.column(at)
        dim = col.type.list_size
        vecs = np.asarray(col.flatten(), np.float32).reshape(-1, dim)
        yield batch.set_column(at, field, vector_array(vecs, sense, width))
