"""The errors a remote memory raises (:class:`~tactus_memory.client.main.Client` and its touch
stream): the library's own exception for a problem type it names
(:data:`~tactus_memory.errors.ERROR_STATUS`), else :class:`RemoteError`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tactus_memory.errors import ERROR_STATUS, OverloadedError, TactusError

#: a problem type's slug -> the library exception the client raises for it
ERROR_BY_SLUG = {slug: cls for cls, (_, slug, _) in ERROR_STATUS.items()}


class RemoteError(TactusError):
    """A problem the service answered that no library error names (401, 413, 500, a 503
    without Retry-After ...). ``status`` and ``problem`` (the problem details) say which."""

    def __init__(self, status: int, problem: Mapping[str, Any]) -> None:
        super().__init__(f"{status} {problem.get('title', '')}: {problem.get('detail', '')}")
        self.status = status
        self.problem = dict(problem)


class AuthenticationError(RemoteError):
    """401/403: no token, or the wrong one."""


def problem_error(
    status: int, problem: Mapping[str, Any], retry: float | None = None
) -> TactusError:
    """Problem details -> the library's exception for their type (or :class:`RemoteError`)."""
    detail = str(problem.get("detail", ""))
    slug = str(problem.get("type", "")).rpartition(":")[2]
    cls = ERROR_BY_SLUG.get(slug)
    if cls is OverloadedError:
        return OverloadedError(detail, retry or 1.0)
    if cls is not None:
        return cls(detail)
    if status in (401, 403):
        return AuthenticationError(status, problem)
    return RemoteError(status, problem)
