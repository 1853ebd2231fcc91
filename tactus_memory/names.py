"""The two name validators every layer uses: item, session and source ids
(:func:`validate_id`) and sense names (:func:`validate_sense_name`), each applying its pattern
from :mod:`tactus_memory.limits`. They sit at the bottom of the base, so the filters
(``where.py``), the sense contract (``senses/base.py``) and the operator's policies
(``policies.py``) all check names the same way without importing each other."""

from __future__ import annotations

from typing import Any

from tactus_memory.errors import InvalidIdError
from tactus_memory.limits import ID_DESCRIPTION, ID_RE, SENSE_NAME_RE


def validate_sense_name(name: str) -> str:
    if not isinstance(name, str) or not SENSE_NAME_RE.fullmatch(name):
        raise InvalidIdError(
            f"invalid sense name {name!r}: use 1-32 chars of [a-z0-9_], starting with a letter"
        )
    return name


def validate_id(value: Any, what: str = "id") -> str:
    """Session ids, item ids and source ids: 1-128 chars of ``[A-Za-z0-9._:-]``."""
    if not isinstance(value, str) or not ID_RE.fullmatch(value):
        shown = (
            repr(value)
            if not isinstance(value, str) or len(value) <= 60
            else repr(value[:60]) + "..."
        )
        raise InvalidIdError(f"invalid {what} {shown}: use {ID_DESCRIPTION.removesuffix('.')}")
    return value
