"""The write path: every blocking library write runs here, in worker threads, few at a time.

``Memory`` serialises its commits with a lock, so many threads waiting on it buy nothing; they
would only hold the threadpool that reads (search, sessions) need. Writes therefore get their
own capacity limiter (``Settings.write_threads``, default 2: one embedding while one commits);
reads keep the default threadpool. A write's coroutine resumes, and its 201 or WebSocket ack
is sent, only after ``Memory.add_many`` returned, i.e. after the LanceDB commit.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import anyio
import anyio.to_thread

T = TypeVar("T")


class Writer:
    def __init__(self, threads: int = 2) -> None:
        self.threads = threads
        self._limiter: anyio.CapacityLimiter | None = None

    async def run(self, func: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        if self._limiter is None:
            self._limiter = anyio.CapacityLimiter(self.threads)
        call = functools.partial(func, *args, **kwargs)
        return await anyio.to_thread.run_sync(call, limiter=self._limiter)
