"""Schemathesis hooks (loaded with SCHEMATHESIS_HOOKS=tests.schemathesis_hooks).

The OpenAPI document states every rule JSON Schema can express. The cross-field rules it
cannot are written in the operations' descriptions and enforced by the server with a 422
naming the rule: ``t_end >= t``, ``after <= before``, and one ``t`` (``t_end``, ``meta``,
``ids``) entry per vector or window, one K for all windows of a batch; a trajectory's times
strictly increasing with one position (and orientation) per time, unit quaternions, a
``near`` radius above 0, ``/at`` given its place once, a touch route's ``?sense=``
naming a windowed sense (which names the server registered, the schema cannot know), and
the generic windowed route's frames having the shape of the sense its path names (one
schema cannot state every sense's frame shape: an IMU's (6,), a glove's (32, 32)). A generated
request that only breaks one of those is schema-valid but rightly refused, so exactly that
failure (ST202 answered by a 422 whose detail names one of these rules) is set aside; every
other failure counts.
"""

from __future__ import annotations

import re
from typing import Any

import schemathesis

#: the server's wording for each cross-field rule (tactus_memory/memory/main.py, store.py,
#: service/routers/touch.py, items.py)
CROSS_FIELD = re.compile(
    r"t_end \(.*\) is before t \("
    r"|after \(.*\) is later than before \("
    r"|has \d+ entries for \d+ (items|vectors|windows)"
    r"|ids must be a list of \d+ ids"
    r"|windows is ragged"  # windows of one batch with different K (frame shapes are in the schema)
    # poses: times strictly increasing, one position (orientation) per time, unit quaternions
    r"|t must be strictly increasing"
    r"|has \d+ rows for \d+ times"
    r"|is not a unit quaternion"
    r"|orientation must be \(N, 4\) quaternions, got shape \(0,\)"  # [] for N > 0 times
    r"|near radius must be > 0"  # near=x,y,z,0: the pattern cannot say r > 0
    r"|/at takes the place as x, y, z and r"
    r"|near/frame select items, not episodes"  # a timeline's episodes have no place
    # ?sense= on a touch route names a sense the server has, but not a windowed one (a
    # vector sense such as `motion`, listed by GET /sessions): the schema cannot know which
    # names the server registered
    r"|sense '[^']+' is a \w+ sense, not touch"
)


#: the generic windowed write (service/routers/touch.py): its frames are (K, *F), F the frame
#: shape of the sense in the path, which its schema cannot state; the edge's wording for a
#: window of another shape, or of values that are no numbers (service/arrays.py)
WINDOWS_PATH = "/sessions/{session}/senses/{sense}/windows"
WINDOW_SHAPE = re.compile(
    r"has shape \(.*\), expected \(|is ragged or not numeric|has values beyond"
)


@schemathesis.hook
def filter_failure(context: Any, failure: Any, case: Any, response: Any) -> bool:
    """Keep every failure except a 422 that names one of the cross-field rules, and ST301 on
    a session's clock: PUT /sessions/{id}/clock may set a clock before the session has items
    (a stream is aligned before it records), so a PUT after the DELETE re-creates it, which
    the use-after-free check does not count as a re-creation. DELETE itself removes the
    offsets (tests/service/test_trust.py::test_deleting_a_session_removes_its_clock_offsets)."""
    if getattr(failure, "code", "") == "ST301" and case.path == "/sessions/{session}/clock":
        return False
    if response is None or response.status_code != 422:
        return True
    if getattr(failure, "code", "") != "ST202":  # "schema-valid request rejected" only
        return True
    detail = _detail(response)
    if case.path == WINDOWS_PATH and WINDOW_SHAPE.search(detail):
        return False  # a window of another shape than the path's sense reads
    return not detail or CROSS_FIELD.search(detail) is None


def _detail(response: Any) -> str:
    """The problem's ``detail`` ("" when the body is not a JSON problem)."""
    try:
        return str(response.json().get("detail", ""))
    except Exception:  # noqa: BLE001  (not JSON)
        return ""
