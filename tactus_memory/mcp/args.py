"""The arguments every MCP tool shares (typed ``Annotated`` aliases: the JSON schema an agent
sees) and :func:`compact`, the one shape of a tool's answer."""

from __future__ import annotations

from typing import Annotated

from mcp.types import CallToolResult, TextContent
from pydantic import BaseModel, Field, Strict

from tactus_memory.limits import ID_DESCRIPTION, ID_PATTERN, MAX_ID_CHARS, MAX_TEXT_CHARS
from tactus_memory.times import StrictSeconds

#: most hits a tool returns at once (an agent reads them all; the library allows MAX_K)
MAX_TOOL_K = 50
#: most timeline items a tool returns at once
MAX_TOOL_ITEMS = 500

# ----------------------------------------------------------------- arguments
#: a number argument: strict, so a JSON ``true`` is refused rather than read as 1.0 (as the
#: HTTP API and the library refuse booleans as numbers)
Number = Annotated[float, Strict()]

QueryArg = Annotated[
    str,
    Field(
        min_length=1,
        max_length=MAX_TEXT_CHARS,
        description="What to look for, in words (e.g. 'holding a warm mug').",
    ),
]
KArg = Annotated[int, Field(ge=1, le=MAX_TOOL_K, description="How many results.")]
SessionArg = Annotated[
    str | None,
    Field(
        pattern=ID_PATTERN,
        max_length=MAX_ID_CHARS,
        description="Only this session (default: every session). " + ID_DESCRIPTION,
    ),
]
SensesArg = Annotated[
    list[str] | None,
    Field(description="Only these senses, e.g. ['touch'] or ['text'] (default: every sense)."),
]
AnchorSensesArg = Annotated[
    list[str] | None, Field(description="Search the anchor only in these senses.")
]
#: a time argument: the one time rule (tactus_memory/times.py), strict as Number
TimeArg = StrictSeconds
AfterArg = Annotated[
    TimeArg | None, Field(description="Only items still going on at or after this time (s).")
]
BeforeArg = Annotated[TimeArg | None, Field(description="Only items started at or before (s).")]
MergeGapArg = Annotated[
    Number, Field(ge=0.0, le=1e9, description="Matches this close (s) count as one occurrence.")
]
WindowsArg = Annotated[
    bool,
    Field(
        description="Touch as single windows. By default a touch answer is a grasp (the "
        "contiguous windows of one hold, scored together)."
    ),
]


def compact(result: BaseModel) -> CallToolResult:
    """One line of JSON as text (what a model reads) and the same object as structured
    content (what a program reads); empty fields are left out."""
    body = result.model_dump(mode="json", exclude_none=True)
    text = result.model_dump_json(exclude_none=True)
    return CallToolResult(content=[TextContent(type="text", text=text)], structured_content=body)
