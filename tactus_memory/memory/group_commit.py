"""Group commit: writes from many sessions and gloves share one embedding call per sense and
ONE LanceDB commit per tick.

```python
with GroupCommitter(memory, tick=0.025) as gc:
    fut = gc.submit("glove-3", "touch", [window], t=[12.5])   # validated now, per write
    ids = fut.result()                                         # returns after the commit
```

How it works: :meth:`GroupCommitter.submit` validates the write in the caller's thread
(:meth:`Memory.prepare_write`, so a bad item fails only its own call, at once) and queues it.
One committer thread takes whatever is queued once the oldest write has waited ``tick``
seconds (or ``max_batch`` items are waiting) and embeds it with one ``embed`` call per sense;
a second thread stores each embedded batch in one commit (:meth:`Memory.commit_writes`), in
the order taken, while the first embeds the next (at most one batch waits between them).
The commit's Arrow table, LanceDB's append and the acknowledgements then no longer stand
between two encoder calls: with one worker they took a quarter of the committer thread
(benchmarks/capacity.py, sampled at saturation). Each write's future resolves only
after that commit returned, so an acknowledged write survives a crash. A write that fails on
its own (its embedding raises, its id is another session's, or another write of the batch
names the same id with other content: 409) is left out and fails alone, and the rest is
committed once; a repeat of the same id with the same session, sense and payload is written
once and both are acknowledged. A batch is never committed twice: a failure after the store
write (bookkeeping) is logged and repaired, and the commit itself is idempotent by id.
The queue is bounded by ``max_pending`` items (queued or being
committed); beyond it :meth:`submit` raises :class:`~tactus_memory.errors.OverloadedError`
with a ``retry_after`` hint (the service answers 503 + ``Retry-After``).

The WAIT is bounded too (``max_wait`` seconds, issue 48): a write still queued ``max_wait``
after it arrived is not embedded or committed but refused with OverloadedError when the
committer reaches it, and :meth:`submit` refuses at once while the oldest queued write has
waited longer than that (the committer is that far behind); and a batch takes no more items
than the committer embeds and commits in about ``max_wait`` at its measured rate. So every
write is either acknowledged within about three times ``max_wait`` (its wait, its batch, and
the one batch ahead of it in the pipeline), or refused: none is answered late, and each gets
an answer.

Why: with one commit per glove window, 64 gloves at 30 Hz (240 windows/s) paid 240 encoder
calls and 240 LanceDB commits per second and acknowledgements fell seconds behind; batched,
they pay about ``1 / tick`` of each.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from typing_extensions import Unpack

from tactus_memory.batches import WriteKwargs
from tactus_memory.errors import OverloadedError
from tactus_memory.memory.encode_process import EncoderProcess
from tactus_memory.memory.main import Memory
from tactus_memory.memory.writes import embed_isolated
from tactus_memory.settings import (
    DEFAULT_COMMIT_MAX_BATCH,
    DEFAULT_COMMIT_MAX_PENDING,
    DEFAULT_COMMIT_TICK_MS,
)
from tactus_memory.storage.rows import PreparedWrite

log = logging.getLogger(__name__)

#: the smallest batch a wait bound lets the committer take (the rate measured on small
#: batches is mostly their fixed cost: the cap grows back from here as batches grow)
MIN_BOUNDED_BATCH = 8


@dataclass
class CommitStats:
    """Counters since start: commits made, writes and items committed, failures, and
    ``batch_retries``: commits that left a failing write out (the rest still committed)."""

    commits: int = 0
    writes: int = 0
    items: int = 0
    failed_writes: int = 0
    batch_retries: int = 0
    rejected: int = 0
    #: writes refused because they waited (or would wait) longer than ``max_wait``
    late: int = 0
    largest_batch: int = 0
    commit_seconds: float = 0.0


@dataclass(eq=False)
class _Queued:
    write: PreparedWrite
    future: Future[list[str]]
    arrived: float
    released: bool = False  # no longer counted as pending


def lower_thread_priority(nice: int) -> None:
    """Add ``nice`` to the calling thread's niceness (Linux schedules threads one by one; on
    a system that does not, the priority stays and it is logged)."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except (OSError, AttributeError) as exc:
        log.warning("could not lower the group committer's priority: %s", exc)


class GroupCommitter:
    """Batches writes of many sessions into one embed per sense and one commit per tick.

    ``encode_threads``: torch intra-op threads of the committer thread while it embeds
    (``torch.set_num_threads`` is per thread), e.g. 1 on a 2-core machine so searches keep
    a core; None leaves torch's default. ``nice``: added to the committer thread's niceness
    (Linux: per thread) so the requests served meanwhile, searches first, get the cores before
    the encoder does; 0 leaves it as it is. ``encoder``: an :class:`EncoderProcess` that
    embeds the senses it serves in its own process (closed with the committer).
    """

    def __init__(
        self,
        memory: Memory,
        *,
        tick: float = DEFAULT_COMMIT_TICK_MS / 1000.0,
        max_batch: int = DEFAULT_COMMIT_MAX_BATCH,
        max_pending: int = DEFAULT_COMMIT_MAX_PENDING,
        retry_after: float = 1.0,
        encode_threads: int | None = None,
        nice: int = 0,
        encoder: EncoderProcess | None = None,
        max_wait: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if tick < 0 or max_batch < 1 or max_pending < 1:
            raise ValueError("tick must be >= 0, max_batch and max_pending >= 1")
        if max_wait is not None and max_wait <= tick:
            raise ValueError("max_wait must be longer than tick (or None: unbounded)")
        self.max_wait = None if max_wait is None else float(max_wait)
        self.clock = clock
        #: items per second the committer embedded and committed, over the last batches (an
        #: average; None: none measured yet): with ``max_wait``, a batch takes at most what
        #: it commits in about that long (:meth:`_batch_cap`)
        self._rate: float | None = None
        self.memory = memory
        self.tick = float(tick)
        self.max_batch = int(max_batch)
        self.max_pending = int(max_pending)
        self.retry_after = float(retry_after)
        self.encode_threads = encode_threads
        self.nice = int(nice)
        self.encoder = encoder
        self.stats = CommitStats()
        self._cond = threading.Condition()
        self._queue: deque[_Queued] = deque()
        self._queued_items = 0
        self._pending_items = 0  # queued + being committed
        self._closing = False
        #: embedded batches (and when their embedding began) on their way to the store thread;
        #: None: the committer thread is done
        self._embedded: queue.Queue[tuple[list[_Queued], float] | None] = queue.Queue(maxsize=1)
        self._thread = threading.Thread(target=self._run, name="tactus-group-commit", daemon=True)
        self._storer = threading.Thread(
            target=self._store_run, name="tactus-group-store", daemon=True
        )
        self._thread.start()
        self._storer.start()

    # ------------------------------------------------------------------ submit
    def submit(
        self, session: str, sense: str, items: Sequence[Any], **kw: Unpack[WriteKwargs]
    ) -> Future[list[str]]:
        """THE write call of every entry point that shares commits (HTTP, the WebSocket
        stream): validate the write now (``Memory.add_many``'s arguments, the sense's
        ``validate`` with ``options``; typed errors raise here, before anything is queued)
        and queue it; the future gives its ids after the commit that stored it. Raises
        OverloadedError when the queue is full."""
        return self._enqueue(self.memory.prepare_write(session, sense, items, **kw))

    def _enqueue(self, write: PreparedWrite) -> Future[list[str]]:
        fut: Future[list[str]] = Future()
        n = len(write)
        if n == 0:
            fut.set_result(write.stored())
            return fut
        with self._cond:
            if self._closing:
                raise RuntimeError("the group committer is closed")
            if self._pending_items and self._pending_items + n > self.max_pending:
                self.stats.rejected += 1
                raise OverloadedError(
                    f"the write queue is full ({self._pending_items} items waiting, limit "
                    f"{self.max_pending}); retry after {self.retry_after:g} s",
                    retry_after=self.retry_after,
                )
            now = self.clock()
            late = self._would_wait(now)
            if late is not None:
                self.stats.rejected += 1
                self.stats.late += 1
                raise self._too_late(late)
            self._queue.append(_Queued(write, fut, now))
            self._queued_items += n
            self._pending_items += n
            self._cond.notify()
        return fut

    def _would_wait(self, now: float) -> str | None:
        """Why a write queued ``now`` would wait longer than ``max_wait`` (None: not known to):
        the oldest queued write already has, so the committer is that far behind. (A rate
        estimate would not do: a batch of 6 windows costs about what one costs, so items/s
        measured on small batches refused writes that were committed in time.) Under the
        condition's lock."""
        if self.max_wait is None or not self._queue:
            return None
        waited = now - self._queue[0].arrived
        if waited > self.max_wait:
            return f"the oldest queued write has waited {waited:.2f} s"
        return None

    def _too_late(self, why: str) -> OverloadedError:
        return OverloadedError(
            f"writes would wait longer than the commit wait bound ({self.max_wait:g} s, "
            f"TACTUS_COMMIT_MAX_WAIT_MS): {why}; not stored, retry after {self.retry_after:g} s",
            retry_after=self.retry_after,
        )

    def add_many(self, session: str, sense: str, items: Sequence[Any], **kw: Any) -> list[str]:
        """Blocking form of :meth:`submit`: returns the ids once committed."""
        return self.submit(session, sense, items, **kw).result()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (submits are refused)."""
        return self._closing

    @property
    def pending(self) -> int:
        """Items queued or being committed."""
        return self._pending_items

    # ------------------------------------------------------------------ lifecycle
    def close(self, timeout: float | None = None) -> None:
        """Commit what is queued, then stop the committer thread."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        until = None if timeout is None else time.monotonic() + timeout
        self._thread.join(timeout)
        self._storer.join(None if until is None else max(0.0, until - time.monotonic()))
        if self.encoder is not None:
            self.encoder.close()

    def __enter__(self) -> GroupCommitter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ committer thread
    def _take(self) -> list[_Queued] | None:
        """Block until a batch is due; None once closed and drained."""
        with self._cond:
            while not self._queue:
                if self._closing:
                    return None
                self._cond.wait()
            deadline = self._queue[0].arrived + self.tick
            while not self._closing and self._queued_items < self.max_batch:
                left = deadline - self.clock()
                if left <= 0:
                    break
                self._cond.wait(left)
            batch: list[_Queued] = []
            n = 0
            now = self.clock()
            cap = self._batch_cap()
            while self._queue and (not batch or n + len(self._queue[0].write) <= cap):
                q = self._queue.popleft()
                self._queued_items -= len(q.write)
                if not q.future.set_running_or_notify_cancel():
                    # the caller gave up before the commit: not stored, not counted
                    self._pending_items -= len(q.write)
                elif self.max_wait is not None and now - q.arrived > self.max_wait:
                    # waited past the bound: refused now, never acknowledged late
                    q.released = True
                    self._pending_items -= len(q.write)
                    self.stats.rejected += 1
                    self.stats.late += 1
                    q.future.set_exception(self._too_late(f"it waited {now - q.arrived:.2f} s"))
                else:
                    batch.append(q)
                    n += len(q.write)
            return batch

    def _batch_cap(self) -> int:
        """Most items in the next batch: ``max_batch``, and with a wait bound no more than the
        committer embeds and commits within it at its measured rate (at least
        :data:`MIN_BOUNDED_BATCH`), so an acknowledged write waits at most about the bound
        in the queue and as long again for its batch (a 256-item batch took ~12 s on a
        loaded 2-core machine: acks came 18 s late with only the queue bounded)."""
        if self.max_wait is None or self._rate is None:
            return self.max_batch
        return max(MIN_BOUNDED_BATCH, min(self.max_batch, int(self._rate * self.max_wait)))

    def _run(self) -> None:
        """The committer thread: take each due batch and embed it, then hand it on."""
        if self.encode_threads is not None:
            import torch

            torch.set_num_threads(self.encode_threads)
        if self.nice:
            lower_thread_priority(self.nice)
        try:
            while True:
                batch = self._take()
                if batch is None:
                    return
                if not batch:
                    continue
                t0 = time.perf_counter()
                try:
                    self._embed(batch)
                except BaseException:  # noqa: BLE001  (commit_writes embeds what is left)
                    log.exception("embedding a batch failed unexpectedly")
                self._embedded.put((batch, t0))
        finally:
            self._embedded.put(None)

    def _embed(self, batch: list[_Queued]) -> None:
        """The batch's vectors: the encoder process's senses there, the rest here (a write
        whose embedding fails gets its ``error`` and fails alone)."""
        writes = [q.write for q in batch]
        if self.encoder is not None:
            self.encoder.embed_writes(writes, self.memory.space.dim)
        embed_isolated([w for w in writes if len(w) and w.vectors is None], self.memory.space.dim)

    def _store_run(self) -> None:
        """The store thread: commit each embedded batch, in the order taken."""
        if self.nice:
            lower_thread_priority(self.nice)
        while True:
            item = self._embedded.get()
            if item is None:
                return
            batch, t0 = item
            try:
                self._commit(batch, t0)
            except BaseException:  # noqa: BLE001  (never leave a future hanging)
                log.exception("group commit failed unexpectedly")
                self._release(batch)
                for q in batch:
                    if not q.future.done():
                        q.future.set_exception(RuntimeError("group commit failed; see the log"))
            finally:
                self._release(batch)

    def _release(self, batch: list[_Queued]) -> None:
        """The batch's items stop counting as pending (once; before its acks go out, so an
        acknowledged caller's next write finds the room its last one left)."""
        with self._cond:
            for q in batch:
                if not q.released:
                    q.released = True
                    self._pending_items -= len(q.write)

    def _commit(self, batch: list[_Queued], t0: float) -> None:
        """ONE commit for the (embedded) batch, never a second: a write that fails on its own
        (its embedding, an id clash) is left out and fails alone; a failing commit fails every
        write of the batch; once it succeeded, every other write is acknowledged whatever
        fails after it (the bookkeeping is logged and repaired by the memory). ``t0``: when
        its embedding began (``commit_seconds`` counts both)."""
        writes = [q.write for q in batch]
        try:
            self.memory.commit_writes(writes, isolate=True)
        except Exception as exc:  # noqa: BLE001  (the commit itself failed: nothing stored)
            self._release(batch)
            self.stats.failed_writes += len(batch)
            log.warning("a commit of %d writes failed: %s", len(batch), exc)
            for q in batch:
                q.future.set_exception(exc)
            return
        self._release(batch)
        try:  # counted before the acks, so a caller acknowledged sees its commit counted
            self._record(batch, time.perf_counter() - t0)
        except Exception:  # noqa: BLE001  (counters only: never keeps a write unacknowledged)
            log.exception("group commit statistics failed")
        for q in batch:
            if q.write.error is not None:
                q.future.set_exception(q.write.error)
            else:
                q.future.set_result(q.write.stored())

    def _record(self, batch: list[_Queued], seconds: float) -> None:
        s = self.stats
        failed = sum(q.write.error is not None for q in batch)
        s.failed_writes += failed
        s.batch_retries += bool(failed)
        s.commits += failed < len(batch)
        s.writes += len(batch) - failed
        items = sum(len(q.write) for q in batch if q.write.error is None)
        s.items += items
        s.largest_batch = max(s.largest_batch, items)
        s.commit_seconds += seconds
        if items and seconds > 0:  # the committer's rate: an average over the last batches
            rate = items / seconds
            self._rate = rate if self._rate is None else 0.7 * self._rate + 0.3 * rate
