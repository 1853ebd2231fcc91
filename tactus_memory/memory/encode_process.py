"""Embedding in a worker process, for the group committer
(:mod:`tactus_memory.memory.group_commit`).

A sense's ``embed`` is many short torch calls, and each one gives up the interpreter lock and
takes it back. In a server whose event loop reads ~2,000 WebSocket frames a second, the
committer's thread waits for that lock at every call (measured: the touch encoder beside a
busy Python thread embeds about half the windows it embeds alone; ``benchmarks/encoder_gil.py``).
:class:`EncoderProcess` runs the batch ``embed`` of chosen senses in one spawned worker
process instead, which has its own interpreter lock: the committer's thread only sends the
validated items and waits (without the lock) for the ``(n, D)`` rows.

The worker rebuilds each sense from its registration (registered name and ``config()``, as
a reopened store does, :mod:`tactus_memory.senses.plugins`), so only a sense that ``create`` can
rebuild without the memory's space is served here (the touch sense: its checkpoint). Until
the worker has started, or if it dies, :meth:`EncoderProcess.embed_writes` leaves the writes
alone and the memory embeds them in the committer's thread as before: nothing waits for the
worker, and an embedding that fails in the worker is tried again there, write by write, so a
bad write still fails alone.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

import numpy as np

from tactus_memory.memory.writes import embed_groups
from tactus_memory.senses.base import Sense
from tactus_memory.senses.plugins import lookup, registered_name
from tactus_memory.storage.rows import PreparedWrite

log = logging.getLogger(__name__)

#: seconds one batch may take in the worker before the committer embeds it itself
EMBED_TIMEOUT_S = 60.0
#: how often the worker checks that the server that started it is still there (seconds)
PARENT_POLL_S = 0.5


class EncoderProcess:
    """One spawned worker that embeds batches for the senses named in ``senses``.

    ``nice``: the worker's niceness (reads in the server get the cores first); ``threads``:
    its torch intra-op threads (None: torch's default)."""

    def __init__(
        self, senses: Sequence[str] = ("touch",), *, nice: int = 0, threads: int | None = None
    ) -> None:
        self.senses = frozenset(senses)
        ctx = multiprocessing.get_context("spawn")  # no fork of a threaded server
        self._pool = ProcessPoolExecutor(
            1, mp_context=ctx, initializer=_start, initargs=(os.getpid(), nice, threads)
        )
        self._started: Future[int] = self._pool.submit(os.getpid)  # starts the worker now
        self.broken = False

    @property
    def ready(self) -> bool:
        """The worker is up (it started, and has not died)."""
        return not self.broken and self._started.done() and self._started.exception() is None

    @property
    def pid(self) -> int | None:
        return self._started.result() if self.ready else None

    def serves(self, sense: Sense) -> bool:
        return sense.name in self.senses and registered_name(sense) is not None

    def embed(self, sense: Sense, items: Sequence[Any]) -> np.ndarray:
        """``sense.embed(items)`` in the worker: N items -> (N, D)."""
        kind = registered_name(sense)
        assert kind is not None  # only served senses come here (serves)
        record = (kind, json.dumps(sense.config(), sort_keys=True))
        return self._pool.submit(_embed, record, list(items)).result(EMBED_TIMEOUT_S)

    def embed_writes(self, writes: Sequence[PreparedWrite], dim: int) -> None:
        """Fill in the vectors of the writes of served senses (one call per sense); on any
        failure those left without vectors are embedded by the memory, in the caller."""
        served = [w for w in writes if w.vectors is None and self.serves(w.sense)]
        if not served or not self.ready:
            return
        try:
            embed_groups(served, dim, embed=self.embed)
        except Exception as exc:  # noqa: BLE001  (the committer's own thread embeds them)
            if self._pool._broken:  # the worker died
                self.broken = True
            log.warning("embedding in the encoder process failed (%s); embedding in-thread", exc)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


_SENSES: dict[tuple[str, str], Sense] = {}


def _start(parent: int, nice: int, threads: int | None) -> None:
    """In the worker, once: follow the server (a SIGKILLed server leaves no worker behind),
    lower its priority, set its torch threads."""
    threading.Thread(target=_exit_with, args=(parent,), daemon=True).start()
    if nice:
        os.nice(nice)
    if threads is not None:
        import torch

        torch.set_num_threads(threads)


def _exit_with(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


def _embed(record: tuple[str, str], items: list[Any]) -> np.ndarray:
    """In the worker: the sense of ``record`` (built once) embeds ``items``."""
    sense = _SENSES.get(record)
    if sense is None:
        kind, config = record
        sense = _SENSES[record] = lookup("sense", kind).create(None, **json.loads(config))
    return np.asarray(sense.embed(items), dtype=np.float32)
