"""The write path's worker threads: parsing and validating large write bodies (touch batches,
``.npy`` bodies, images) off the event loop, few at a time.

They are not the read pool: reads keep the default threadpool. The embedding and the LanceDB
commit itself run on the group committer's own thread (``tactus_memory.memory.group_commit``); a
write's
coroutine resumes, and its 201 or WebSocket ack is sent, only after that commit returned.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import anyio
import anyio.to_thread

T = TypeVar("T")


class WriteThreads:
    """A few worker threads (a capacity limiter) that parse and validate write bodies and
    queue them for the group committer: they never commit themselves."""

    def __init__(self, threads: int = 2) -> None:
        self.threads = threads
        self._limiter: anyio.CapacityLimiter | None = None

    async def run(self, func: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        if self._limiter is None:
            self._limiter = anyio.CapacityLimiter(self.threads)
        call = functools.partial(func, *args, **kwargs)
        return await anyio.to_thread.run_sync(call, limiter=self._limiter)
