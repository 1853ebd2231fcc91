"""Run test work on threads so that a failure inside a thread fails the test.

An ``assert`` (or any exception) in a plain ``threading.Thread`` only prints a warning
(``PytestUnhandledThreadExceptionWarning``) and the test passes; :func:`run_threads` collects
what each thread raised and re-raises the first in the calling thread."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from typing import Any


def run_threads(
    target: Callable[..., Any], args: Iterable[tuple[Any, ...]], timeout: float = 300.0
) -> None:
    errors: list[BaseException] = []
    lock = threading.Lock()

    def guarded(*a: Any) -> None:
        try:
            target(*a)
        except BaseException as exc:  # noqa: BLE001  (re-raised in the caller below)
            with lock:
                errors.append(exc)

    threads = [threading.Thread(target=guarded, args=a) for a in args]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout)
    hung = sum(t.is_alive() for t in threads)
    assert not hung, f"{hung} thread(s) still running after {timeout} s"
    if errors:
        raise errors[0]
