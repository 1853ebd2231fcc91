"""Run test work on threads so that a failure inside a thread fails the test.

An ``assert`` (or any exception) in a plain ``threading.Thread`` only prints a warning
(``PytestUnhandledThreadExceptionWarning``) and the test passes; :class:`ThreadErrors`
collects what each thread raised for the calling thread to re-raise, and :func:`run_threads`
runs a batch of threads that way."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from typing import Any


class ThreadErrors:
    """What worker threads raised: :meth:`wrap` a thread's target, then :meth:`raise_first`
    in the calling thread after joining. ``on_error`` runs in the thread that failed (e.g.
    to wake a caller waiting on an event)."""

    def __init__(self, on_error: Callable[[], None] | None = None) -> None:
        self.errors: list[BaseException] = []
        self.on_error = on_error
        self.lock = threading.Lock()

    def wrap(self, target: Callable[..., Any]) -> Callable[..., None]:
        def guarded(*a: Any) -> None:
            try:
                target(*a)
            except BaseException as exc:  # noqa: BLE001  (re-raised in the caller)
                with self.lock:
                    self.errors.append(exc)
                if self.on_error is not None:
                    self.on_error()

        return guarded

    def raise_first(self) -> None:
        with self.lock:
            if self.errors:
                raise self.errors[0]


def run_threads(
    target: Callable[..., Any], args: Iterable[tuple[Any, ...]], timeout: float = 300.0
) -> None:
    errors = ThreadErrors()
    threads = [threading.Thread(target=errors.wrap(target), args=a) for a in args]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout)
    hung = sum(t.is_alive() for t in threads)
    assert not hung, f"{hung} thread(s) still running after {timeout} s"
    errors.raise_first()
