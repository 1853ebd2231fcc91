"""Typed exceptions. Every bad input raises one of these with a message naming the problem.

They subclass ``ValueError`` / ``LookupError`` so plain ``except ValueError`` still works;
the service maps each class to one HTTP status in one place.
"""

from __future__ import annotations


class TactusError(Exception):
    """Base class of every error this package raises on purpose."""


class InvalidInputError(TactusError, ValueError):
    """Input has the wrong shape, dtype, range, or contains NaN/inf (HTTP 422)."""


class InvalidIdError(InvalidInputError):
    """A session id, item id or sense name fails validation (HTTP 422)."""


class DimensionMismatchError(InvalidInputError):
    """A vector's dimension differs from the space or sense dimension (HTTP 422)."""


class UnknownSenseError(TactusError, LookupError):
    """A sense name that is not registered with this memory (HTTP 404)."""


class NotFoundError(TactusError, LookupError):
    """A session or item that does not exist (HTTP 404)."""


class UnknownTenantError(NotFoundError):
    """A tenant no key names and no database holds (HTTP 404 ``unknown-tenant``): the server
    never creates a tenant for a request (``storage.tenants.tenant_exists``)."""


class SenseConflictError(TactusError, ValueError):
    """``add_sense`` with a duplicate name, or a sense bound to another space (HTTP 409)."""


class SenseSwappedError(SenseConflictError):
    """A write embedded by an encoder the store no longer records for its sense: a
    re-embedding (maybe by another process, ``tactus reembed``) swapped the sense to another
    checkpoint. Refused whole (HTTP 409), so a store never holds vectors of two encoders;
    the memory rebuilds the sense from the store's record when it can, and the write sent
    again is embedded by the new encoder."""


class IdConflictError(TactusError, ValueError):
    """An explicit item id already names a row of another session or another sense (HTTP 409).

    Ids are global in a store, but a write may only replace its own rows: re-adding an id
    in the same session and sense is an idempotent upsert; the same id in another session
    or sense is refused, so no writer can overwrite or move another session's items.
    """


class SpaceMismatchError(TactusError, ValueError):
    """A store opened with a space other than the one it was created with (HTTP 409)."""


class CapabilityError(TactusError, ValueError):
    """The space cannot do what was asked, e.g. image embedding without vision (HTTP 400)."""


class DataFormatError(TactusError, ValueError):
    """A STAG file is missing fields or has inconsistent shapes."""


class RecordingError(DataFormatError):
    """A recording that cannot be read (corrupt, truncated, not MCAP / ROS 2 bag), or a
    mapped topic whose messages cannot be turned into the mapped sense (HTTP 422)."""


class DynamicRangeError(TactusError, ValueError):
    """Calibrated pressure uses too few intensity levels or looks already normalised."""


class IdleWindowError(InvalidInputError):
    """A touch window with no contact (an idle hand): the touch sense never stores one as a
    grasp, whichever way it arrives (``tactus_memory.touch.windows``)."""


class SpaceConfigError(TactusError, ValueError):
    """A space cannot be built as asked: its model folder is missing, not given, or holds
    another model than the one a store was created with. One line naming the option to pass."""


class OverloadedError(TactusError):
    """A bounded write queue is full: retry after ``retry_after`` seconds (HTTP 503)."""

    def __init__(self, message: str, retry_after: float = 1.0) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class PoseConflictError(TactusError):
    """Poses re-sent for times a session's trajectory already holds (in that frame): refused
    whole (HTTP 409), naming the times; nothing is written."""


class ThrottledError(TactusError):
    """Too many secret checks for one key id this second (each is a scrypt): retry after
    ``retry_after`` seconds (HTTP 429). Says nothing of whether the presented key is right."""

    def __init__(self, message: str, retry_after: float = 1.0) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class StoreDamagedError(TactusError):
    """The store fails its integrity check (a data file missing or truncated, a manifest
    unreadable): writes are refused so nothing lands in a store that cannot be read back
    (HTTP 503). ``tactus maintain --check`` lists the damage."""


#: exception class -> (HTTP status, problem type slug, title): how the service answers each
#: error (``service/problems.py``, the most specific class wins, MRO order) and how
#: ``tactus_memory.Client`` raises it again from the problem's type.
ERROR_STATUS: dict[type[TactusError], tuple[int, str, str]] = {
    InvalidIdError: (422, "invalid-id", "Invalid identifier"),
    DimensionMismatchError: (422, "dimension-mismatch", "Dimension mismatch"),
    InvalidInputError: (422, "invalid-input", "Invalid input"),
    UnknownSenseError: (404, "unknown-sense", "Unknown sense"),
    NotFoundError: (404, "not-found", "Not found"),
    UnknownTenantError: (404, "unknown-tenant", "Unknown tenant"),
    SenseConflictError: (409, "sense-conflict", "Sense conflict"),
    SenseSwappedError: (409, "sense-swapped", "Sense re-embedded to another encoder"),
    IdConflictError: (409, "id-conflict", "Item id conflict"),
    SpaceMismatchError: (409, "space-mismatch", "Space mismatch"),
    CapabilityError: (400, "capability", "Not supported by this memory"),
    DataFormatError: (422, "data-format", "Invalid data format"),
    DynamicRangeError: (422, "dynamic-range", "Insufficient dynamic range"),
    IdleWindowError: (422, "idle-window", "Idle touch window"),
    OverloadedError: (503, "overloaded", "Write queue full"),
    ThrottledError: (429, "throttled", "Too many key checks"),
    PoseConflictError: (409, "pose-conflict", "Poses already stored"),
    StoreDamagedError: (503, "store-damaged", "Store is damaged"),
}
