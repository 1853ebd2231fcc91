"""The one rule for a time a client sends (issue 48), used by every door: the pydantic schemas
and query parameters of the service, the WebSocket stream, the MCP tools, the Client, the CLI,
the recordings ingest and the library's own write and read paths.

A time is a number of **seconds** (any clock: Unix time, or seconds since a session started):

- a real number, never a boolean or a string (``true`` is not 1, ``"3"`` is not 3);
- finite (NaN and +-inf are refused);
- ``|t| <= MAX_SECONDS`` (1e10 s, about 317 years either side of the clock's zero). Beyond it
  float64 stops resolving the seconds the temporal reads step by (at 1e18, ``t + 30`` is
  ``t``); a value that looks like nanoseconds (a ROS stamp, about 1.7e18), microseconds or
  milliseconds is refused with a message that says so ("seconds, not nanoseconds?").

:func:`check_time` is the rule (a typed :class:`~tactus_memory.errors.InvalidInputError`);
:data:`Seconds` is the same rule as a pydantic type (the schemas' 422 and the JSON schema's
``minimum``/``maximum``); :data:`StrictSeconds` also refuses booleans and strings where the
caller's model is lax (the MCP tools' arguments).
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import AfterValidator, Field, Strict

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_SECONDS

#: what a time too large for seconds most likely is: (smallest magnitude, unit). Today's
#: Unix time (~1.8e9 s) is ~1.8e12 in ms, ~1.8e15 in us and ~1.8e18 in ns
LOOKS_LIKE = ((1e17, "nanoseconds"), (1e14, "microseconds"), (1e11, "milliseconds"))

#: the rule in one sentence (the docs' trust page, the schema's descriptions)
RULE = f"seconds, a finite number with |t| <= {MAX_SECONDS:g}"


def check_time(value: Any, what: str = "t") -> float:
    """``value`` as a time in seconds (the module's rule), else InvalidInputError naming it."""
    # numpy scalars are numbers too (a recording's stamps); booleans, strings and the rest not
    if isinstance(value, (str, bytes, bool)) or not hasattr(value, "__float__"):
        raise InvalidInputError(f"{what} must be a number of seconds, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InvalidInputError(f"{what} must be a number of seconds, got {value!r}") from None
    if not math.isfinite(out):
        raise InvalidInputError(f"{what} must be a finite number of seconds, got {value!r}")
    if abs(out) > MAX_SECONDS:
        unit = next((name for bound, name in LOOKS_LIKE if abs(out) >= bound), None)
        hint = f" (seconds, not {unit}?)" if unit else ""
        raise InvalidInputError(f"{what} = {out:g} is out of range: times are {RULE}{hint}")
    return out


def _checked(value: float) -> float:
    return check_time(value, "time")


_SCHEMA = Field(
    description=f"Time in {RULE}.",
    json_schema_extra={"minimum": -MAX_SECONDS, "maximum": MAX_SECONDS},
)
#: a time in seconds as a pydantic field (a 422 / validation error quoting the rule)
Seconds = Annotated[float, AfterValidator(_checked), _SCHEMA]
#: the same, strict: a JSON boolean or string is refused, not read as 1.0 or 3.0
StrictSeconds = Annotated[float, Strict(), AfterValidator(_checked), _SCHEMA]
