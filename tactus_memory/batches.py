"""A write batch's values, checked: per-item lists, times, ids, meta. Shared by the memory's
write path (:func:`tactus_memory.storage.rows.check_batch`) and the remote client, which checks
a batch before it sends it, so both refuse the same batches with the same messages."""

from __future__ import annotations

import json
import re
import time
import uuid
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, TypedDict

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_BATCH, MAX_META_BYTES, MAX_META_DEPTH
from tactus_memory.names import validate_id
from tactus_memory.signatures import reject_unknown
from tactus_memory.times import check_time


class BatchKwargs(TypedDict, total=False):
    """The keywords of one write batch (``Memory.add_many``, ``GroupCommitter.submit``)."""

    t: Sequence[float | None] | float | None
    t_end: Sequence[float | None] | float | None
    meta: Sequence[dict[str, Any] | None] | dict[str, Any] | None
    ids: Sequence[str] | None
    source: str
    position: Any
    frame: str


class WriteKwargs(BatchKwargs, total=False):
    """:class:`BatchKwargs` plus the sense's ``validate`` options (``Memory.add_many``)."""

    options: Mapping[str, Any] | None
    #: skip the items the sense finds idle (their indices in ``Stored.skipped``); False
    #: raises ``IdleWindowError`` (``Memory.add``, one window: there is nothing else to store)
    skip_idle: bool


class AddKwargs(TypedDict, total=False):
    """The keywords of one item's write (``Memory.add``, ``Client.add``): ``t`` defaults to
    now (unix seconds), ``t_end`` to ``t``; ``id`` makes the call an idempotent upsert of that
    session's item of that sense; ``options`` go to the sense's ``validate``."""

    t: float | None
    t_end: float | None
    meta: dict[str, Any] | None
    id: str | None
    source: str
    options: Mapping[str, Any] | None


def one_item(kw: Mapping[str, Any]) -> WriteKwargs:
    """An ``add`` call's keywords (:class:`AddKwargs`) -> the batch of one item's
    keywords for ``add_many``. Unknown keywords raise TypeError, as a misspelt keyword
    argument would."""
    reject_unknown(kw, AddKwargs.__annotations__)
    item_id = kw.get("id")
    return WriteKwargs(
        t=[kw.get("t")],
        t_end=[kw.get("t_end")],
        meta=[kw.get("meta")],
        ids=None if item_id is None else [item_id],
        source=kw.get("source", ""),
        options=kw.get("options"),
    )


def nesting_depth(value: Any, limit: int) -> int:
    """How deep dicts and lists nest in ``value`` (a scalar 0, ``{}`` 1), counted without
    recursion and given up past ``limit`` (returns ``limit + 1``): a hostile value deep
    enough to overflow a recursive walk is answered at once."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        node, depth = todo.pop()
        children: Iterable[Any]
        if isinstance(node, dict):
            children = node.values()
        elif isinstance(node, (list, tuple)):
            children = node
        else:
            continue
        deepest = max(deepest, depth)
        if deepest > limit:
            return limit + 1
        todo.extend((child, depth + 1) for child in children)
    return deepest


_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')
_NOT_BRACKET = re.compile(rb"[^\[\]{}]")


def json_depth(body: bytes) -> int:
    """How deep arrays and objects nest in the JSON text ``body`` (strings skipped; no
    parse, so no recursion however deep it is): the MCP doors refuse a request deeper than
    ``limits.MAX_JSON_DEPTH`` before any parser sees it."""
    brackets = _NOT_BRACKET.sub(b"", _JSON_STRING.sub(b"", body))
    depth = deepest = 0
    for c in brackets:
        depth += 1 if c in b"[{" else -1
        deepest = max(deepest, depth)
    return deepest


def meta_json(meta: Any) -> str:
    if meta is None:
        return "{}"
    if not isinstance(meta, dict) or not all(isinstance(key, str) for key in meta):
        raise InvalidInputError("meta must be a dict with string keys")
    if nesting_depth(meta, MAX_META_DEPTH) > MAX_META_DEPTH:
        raise InvalidInputError(f"meta nests deeper than {MAX_META_DEPTH} levels")
    try:
        out = json.dumps(meta, allow_nan=False, sort_keys=True, ensure_ascii=False)
        size = len(out.encode())
    except UnicodeEncodeError:
        raise InvalidInputError(
            "meta contains a lone surrogate (e.g. '\\udfff'), which is not valid Unicode"
        ) from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"meta is not JSON-serialisable: {exc}") from None
    if size > MAX_META_BYTES:
        raise InvalidInputError(f"meta is larger than {MAX_META_BYTES} bytes as JSON")
    return out


def per_item(value: Any, n: int, what: str) -> list[Any]:
    """A list of n values, or a scalar/None broadcast to n."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise InvalidInputError(f"{what} has {len(value)} entries for {n} items")
        return list(value)
    return [value] * n


def check_times(
    n: int, t: Sequence[float | None] | float | None, t_end: Sequence[float | None] | float | None
) -> tuple[list[float], list[float], float]:
    """n start and end times (``t`` defaults to now, ``t_end`` to ``t``), and that now."""
    if n > MAX_BATCH:
        raise InvalidInputError(f"{n} items in one call; limit {MAX_BATCH}")
    now = time.time()
    ts = [now if x is None else check_time(x, "t") for x in per_item(t, n, "t")]
    ends = [
        ts[i] if x is None else check_time(x, "t_end")
        for i, x in enumerate(per_item(t_end, n, "t_end"))
    ]
    for a, b in zip(ts, ends, strict=True):
        if b < a:
            raise InvalidInputError(f"t_end ({b}) is before t ({a})")
    return ts, ends, now


def check_ids(n: int, ids: Sequence[str] | None) -> list[str]:
    """The n ids given (an upsert), checked and distinct, or n new ones."""
    if ids is None:
        return [uuid.uuid4().hex for _ in range(n)]
    if isinstance(ids, str) or len(ids) != n:
        raise InvalidInputError(f"ids must be a list of {n} ids")
    id_list = [validate_id(i, "item id") for i in ids]
    if len(set(id_list)) != n:
        raise InvalidInputError("ids contain duplicates")
    return id_list
