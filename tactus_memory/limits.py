"""One home for the library's limits and name/id patterns; the service imports these too.

Every number here is a product decision (bounded work per call), not a measured constant.
"""

from __future__ import annotations

import re

#: the most hits / moments one search returns
MAX_K = 1000
#: the longest text item or query, in characters (MiniLM truncates at 256 tokens anyway)
MAX_TEXT_CHARS = 8192
#: the largest ``meta`` dict, as JSON bytes
MAX_META_BYTES = 65_536
#: the deepest nesting of a ``meta`` dict (objects and lists inside it; the dict itself is 1)
MAX_META_DEPTH = 32
#: the deepest nesting of a JSON request body the MCP endpoint reads (its envelope, the
#: tool's arguments and a meta at MAX_META_DEPTH fit well within it)
MAX_JSON_DEPTH = 64
#: the most items one ``add_many`` call writes
MAX_BATCH = 100_000
#: the longest session / item / source id
MAX_ID_CHARS = 128
#: the most frames in one touch window (a request's window, a stream's window and stride)
MAX_WINDOW_FRAMES = 512

#: sense names: 1-32 characters of [a-z0-9_], starting with a letter
SENSE_NAME_PATTERN = r"^[a-z][a-z0-9_]{0,31}$"
#: session, item and source ids
ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$"
#: a source (stream) id: an id, or '' for none
SOURCE_PATTERN = r"^$|" + ID_PATTERN
ID_DESCRIPTION = "1-128 characters of [A-Za-z0-9._:-], starting with a letter or digit."

SENSE_NAME_RE = re.compile(SENSE_NAME_PATTERN)
ID_RE = re.compile(ID_PATTERN)

#: largest |coordinate| and place radius, in metres (a million km: any robot's world, and
#: r * r of the place filter stays a finite number)
MAX_COORDINATE = 1e9
#: a frame name (``map``, ``odom``, ``base_link``): an id, with ROS 1's leading ``/`` allowed
FRAME_PATTERN = r"^/?[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$"
#: ``near=x,y,z,r`` in a query string: plain decimals (below MAX_COORDINATE), r not negative
_DECIMAL = r"[0-9]{1,9}(\.[0-9]{1,12})?"
NEAR_PATTERN = rf"^-?{_DECIMAL},-?{_DECIMAL},-?{_DECIMAL},{_DECIMAL}$"

#: largest clock offset in seconds (about 317 years): keeps t_aligned = t + offset finite
MAX_CLOCK_OFFSET = 1e10
#: the default staleness bound between replicas (issue 11 target: visibility <= 2 s)
DEFAULT_READ_CONSISTENCY_S = 1.0
#: the largest |t| in seconds any time a client sends may have (about 317 years either side of
#: its clock's zero; Unix time reaches it in 2286): at this magnitude a float64 still resolves
#: microseconds, so t +- a few seconds is a different number (at 1e18, +-30 s rounds back to
#: t). A product decision, not a measurement (issue 48: tactus_memory/times.py)
MAX_SECONDS = 1e10

#: Unicode format characters (category Cf: bidi overrides such as U+202E, zero-width spaces
#: and joiners, the BOM, tag characters), as (first, last) code points of Unicode 15.1; a
#: unit test checks them against the interpreter's ``unicodedata``. Refused in the names a
#: person reads (taught labels, a sense's encoder/version/space): they make a name display
#: as another one (issue 48)
FORMAT_CHAR_RANGES = (
    (0x00AD, 0x00AD), (0x0600, 0x0605), (0x061C, 0x061C), (0x06DD, 0x06DD),
    (0x070F, 0x070F), (0x0890, 0x0891), (0x08E2, 0x08E2), (0x180E, 0x180E),
    (0x200B, 0x200F), (0x202A, 0x202E), (0x2060, 0x2064), (0x2066, 0x206F),
    (0xFEFF, 0xFEFF), (0xFFF9, 0xFFFB), (0x110BD, 0x110BD), (0x110CD, 0x110CD),
    (0x13430, 0x1343F), (0x1BCA0, 0x1BCA3), (0x1D173, 0x1D17A), (0xE0001, 0xE0001),
    (0xE0020, 0xE007F),
)  # fmt: skip
#: the same as a regular-expression class body (the characters themselves: every regex
#: engine of the schema's readers takes them)
FORMAT_CHARS = "".join(chr(a) if a == b else f"{chr(a)}-{chr(b)}" for a, b in FORMAT_CHAR_RANGES)
#: a free name a person reads: no control characters, no format characters
NAME_PATTERN = rf"^[^\x00-\x1f\x7f-\x9f{FORMAT_CHARS}]*$"
