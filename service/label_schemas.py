"""Request and response models of the teaching routes (``routers/labels.py``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from tactus_memory.limits import SENSE_NAME_PATTERN
from tactus_memory.results import Teaching
from tactus_memory.search.teaching import LABEL_PATTERN, MAX_LABEL_CHARS, validate_label
from tactus_memory.service.schemas import Strict
from tactus_memory.times import Seconds


def _label(value: str) -> str:
    validate_label(value)
    return value


class LabelIn(Strict):
    """A span of the session marked "holding <label>"."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"label": "drill", "t": 12.0, "t_end": 15.5}]}
    )

    # the pattern is stated in the schema and checked by the library's validate_label, whose
    # 422 names the problem (an invisible format character: its code point)
    label: Annotated[str, AfterValidator(_label)] = Field(
        min_length=1,
        max_length=MAX_LABEL_CHARS,
        description="What was held, in words (no control or format characters).",
        json_schema_extra={"pattern": LABEL_PATTERN},
    )
    t: Seconds | None = Field(
        None, description="Start of the span (seconds, the session clock); none: from the start."
    )
    t_end: Seconds | None = Field(
        None, description="End of the span (>= t); none: to the end of the session."
    )
    sense: str = Field(
        "touch",
        pattern=SENSE_NAME_PATTERN,
        description="The sense whose windows were the grasp (a sensed modality: the text "
        "sense is refused, 422).",
        json_schema_extra={"not": {"const": "text"}},
    )


class TaughtOut(Teaching):
    """A taught span, as the service answers it."""


class TaughtListOut(BaseModel):
    labels: list[TaughtOut]


class ForgottenOut(BaseModel):
    deleted: int
