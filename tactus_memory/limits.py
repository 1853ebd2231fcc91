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
