"""Bulk work on Ray (the ``ray`` extra): ``tactus ingest FILES... --ray [ADDRESS]`` and
``tactus reembed ... --ray [ADDRESS]`` as Ray Data jobs, for work one machine cannot do (a
month of bags, a new touch checkpoint over every stored window).

* **Ingest** (:func:`ingest_on_ray`): the driver plans, sets the session clock and stores
  the poses exactly as the local path does (:class:`~tactus_memory.recordings.ingest.IngestJob`);
  then each (file, topic) is one unit of work: a worker decodes it with the same
  :class:`~tactus_memory.recordings.decoding.DecodeSpec` (so the same ids), drops ids already
  stored, embeds in batches and hands Arrow rows of the items table to Lance's own Ray writer
  (``lance_ray.write_lance``): ONE commit per group of ``files_per_commit`` files. A re-run
  adds nothing; a killed job loses at most its uncommitted group, redone by the re-run. Items
  are then placed from the session's poses (one merge-insert, ``Places.place_items``).
* **Re-embed** (:func:`reembed_on_ray`): the stored rows of the sense are read with
  ``lance_ray.read_lance``, embedded by workers and appended to the staging table in one
  commit; the swap is the local path's (:func:`tactus_memory.memory.reembed.swap`): one
  merge-insert, readers see all old or all new vectors.

Workers are Ray actors of one CPU each (``workers``, default every CPU of the cluster); the
senses travel to them pickled (a space pickles as its settings, its model reloads there), and
recording files and the store must be reachable from every node (a shared folder or object
storage). ``ray`` is imported here only: the server and the other commands never load it.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Generator, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.reembed import (
    REEMBED_BATCH,
    Reembeddable,
    ReembedReport,
    begin,
    embed_rows,
    staging_schema,
    swap,
    vector_table,
)
from tactus_memory.memory.writes import embed_groups
from tactus_memory.recordings.decoding import Tally
from tactus_memory.recordings.ingest import IngestSummary, plan_ingest
from tactus_memory.recordings.reader import open_recording
from tactus_memory.storage.rows import PreparedWrite, check_batch, writes_table
from tactus_memory.where import Where

if TYPE_CHECKING:
    import pyarrow as pa

    from tactus_memory.recordings.decoding import DecodeSpec
    from tactus_memory.senses.base import Sense

#: ``--ray`` without an address: a Ray instance started on this machine
LOCAL = "local"
#: files per Ray job, each job one commit: what a killed ingest loses at most
FILES_PER_COMMIT = 64
INSTALL = "pip install 'tactus-memory[ray]'"


def default_address(given: str | None = None) -> str:
    """``given``, else $RAY_ADDRESS (Ray's own variable), else :data:`LOCAL`."""
    return given or os.environ.get("RAY_ADDRESS") or LOCAL


def connect(address: str | None = None, workers: int | None = None) -> int:
    """Join the Ray cluster at ``address`` (:func:`default_address`; ``"local"``: start one
    here with ``workers`` CPUs), unless this process already joined one; returns how many
    one-CPU workers the jobs use (``workers``, capped at the cluster's CPUs)."""
    if workers is not None and workers < 1:
        raise InvalidInputError(f"workers must be >= 1, got {workers}")
    try:
        import ray
    except ImportError:
        raise ImportError(f"--ray needs the ray extra: {INSTALL}") from None
    if not ray.is_initialized():
        kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        address = default_address(address)
        if address == LOCAL:
            ray.init(address=LOCAL, num_cpus=workers, **kw)
        else:
            ray.init(address=address, **kw)
    cpus = int(ray.cluster_resources().get("CPU", 1))
    return max(1, min(workers or cpus, cpus))


def _lance_ray() -> Any:
    try:
        import lance_ray
    except ImportError:
        raise ImportError(f"--ray needs Lance's Ray integration: {INSTALL}") from None
    return lance_ray


def _pool(n: int) -> Any:
    """``n`` workers, one Ray actor (one CPU) each."""
    import ray.data

    return ray.data.ActorPoolStrategy(size=n)


def _shippable(what: str, obj: Any) -> None:
    """Fail before any work when ``obj`` cannot travel to a Ray worker (Ray's pickler)."""
    from ray import cloudpickle

    try:
        cloudpickle.dumps(obj)
    except Exception as exc:  # noqa: BLE001  (any pickling failure, named)
        raise InvalidInputError(f"{what} cannot be sent to Ray workers: {exc}") from None


def _torch_threads(n: int) -> None:
    import torch

    torch.set_num_threads(n)


# --------------------------------------------------------------------------- ingest
class _Tally:
    """A Ray actor: what the workers counted (messages, skip reasons, ids already stored); a
    unit that Ray retries after a worker died is counted again (the rows are not: they are
    committed once, and ``rows`` are counted in the store)."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()

    def add(self, counts: dict[str, int]) -> None:
        self.counts.update(counts)

    def get(self) -> dict[str, int]:
        return dict(self.counts)


class _IngestWorker:
    """One Ray actor (one CPU): decodes a (file, topic) unit, skips stored ids, embeds."""

    def __init__(self, spec: DecodeSpec, senses: dict[str, Sense], schema: pa.Schema,
                 uri: str, storage_options: dict[str, str] | None, dim: int, batch: int,
                 tally: Any) -> None:  # fmt: skip
        _torch_threads(1)
        self.spec, self.senses, self.schema, self.dim = spec, senses, schema, dim
        self.uri, self.storage_options = uri, storage_options
        self.batch, self.tally = batch, tally

    def __call__(self, units: dict[str, Any]) -> Iterator[pa.Table]:
        import lance

        stored = lance.dataset(self.uri, storage_options=self.storage_options)
        for path, topic in zip(units["path"], units["topic"], strict=True):
            tally = Tally()
            chunk: list[Any] = []
            items = self.spec.items(open_recording(str(path)), self.senses, tally, [str(topic)])
            existing = 0
            for d in items:
                chunk.append(d)
                if len(chunk) >= self.batch:
                    existing += yield from self._rows(stored, chunk)
                    chunk = []
            if chunk:
                existing += yield from self._rows(stored, chunk)
            self.tally.add.remote(
                {"messages": tally.messages, "existing": existing}
                | {f"skipped:{k}": v for k, v in tally.skipped.items()}
            )

    def _rows(self, stored: Any, chunk: list[Any]) -> Generator[pa.Table, None, int]:
        """The items table rows of ``chunk`` less the ids already stored; returns how many
        were stored before."""
        ids = [d.id for d in chunk]
        there = stored.to_table(columns=["id"], filter=Where().ids(ids).sql())
        present = set(there.column("id").to_pylist())
        keep = [d for d in chunk if d.id not in present]
        if keep:
            plan = self.spec.plan[keep[0].topic]
            batch = check_batch(len(keep), [d.t for d in keep], [d.t_end for d in keep],
                                [d.meta for d in keep], [d.id for d in keep])  # fmt: skip
            write = PreparedWrite(self.spec.session, self.senses[plan.sense],
                                  [d.item for d in keep], batch, plan.source)  # fmt: skip
            embed_groups([write], self.dim)
            yield writes_table(self.schema, [write])
        return len(chunk) - len(keep)


def _session_counts(memory: Any, session: str) -> Counter[str]:
    col = memory.store.scan(Where().session(session).sql(), ["sense"]).column("sense")
    return Counter(col.to_pylist())


def ingest_on_ray(
    memory: Any,
    paths: Any,
    *,
    address: str | None = None,
    workers: int | None = None,
    files_per_commit: int = FILES_PER_COMMIT,
    **kw: Any,
) -> IngestSummary:
    """:func:`tactus_memory.recordings.ingest.ingest_recording` (its keywords) as Ray Data
    jobs; the summary is the local path's (rows: new rows per sense)."""
    import ray

    n = connect(address, workers)
    lr = _lance_ray()
    started = time.perf_counter()
    job = plan_ingest(memory, paths, **kw)
    senses = {p.sense: memory.senses[p.sense] for p in job.plan.values() if not p.skip_reason}
    for name, sense in senses.items():
        _shippable(f"sense {name!r}", sense)
    spec = job.start()  # the session clock and the poses, as the local path
    before = _session_counts(memory, job.session)
    store = memory.store
    uri, options = store.items.uri, store.storage_options or None
    tally = ray.remote(_Tally).options(num_cpus=0).remote()
    worker_kw = {"spec": spec, "senses": senses, "schema": store.schema, "uri": uri,
                 "storage_options": options, "dim": memory.space.dim,
                 "batch": job.batch_size, "tally": tally}  # fmt: skip
    per_job = max(1, int(files_per_commit))
    for at in range(0, len(job.recs), per_job):
        units = [{"path": str(rec.path), "topic": info.topic}
                 for rec in job.recs[at : at + per_job] for info in rec.topics()
                 if info.topic in job.plan and info.count]  # fmt: skip
        if not units:
            continue
        ds = ray.data.from_items(units, override_num_blocks=len(units))
        ds = ds.map_batches(_IngestWorker, fn_constructor_kwargs=worker_kw, batch_size=1,
                            batch_format="numpy", compute=_pool(n), num_cpus=1)  # fmt: skip
        _write(lr, ds, uri, store.schema, options)  # ONE commit for these files
    counts = ray.get(tally.get.remote())
    _after_write(memory, job.session)
    new = _session_counts(memory, job.session) - before
    job.rows.update(new)
    job.existing = counts.get("existing", 0)
    skipped = {k.split(":", 1)[1]: v for k, v in counts.items() if k.startswith("skipped:")}
    job.tally = Tally(counts.get("messages", 0), Counter(skipped))
    return job.summary(spec, time.perf_counter() - started)


def _write(lr: Any, ds: Any, uri: str, schema: pa.Schema, options: dict[str, str] | None) -> None:
    """Append ``ds`` to the Lance dataset at ``uri`` through lance-ray: fragments written by
    tasks (no CPU reserved: the workers hold them), one commit by the driver."""
    lr.write_lance(ds, uri, schema=schema, mode="append", storage_options=options,
                   ray_remote_args={"num_cpus": 0})  # fmt: skip


def _after_write(memory: Any, session: str) -> None:
    """What a commit through the memory does after it: fresh reads, counts re-read, items
    placed from the session's poses."""
    memory.store.items.checkout_latest()
    memory.registry.forget_counts()
    if memory.places.poses.trajectories(session):
        memory.places.place_items(session)


# --------------------------------------------------------------------------- reembed
class _ReembedWorker:
    """One Ray actor (one CPU): stored rows (id, raw, text) -> staged (id, vector, tag)."""

    def __init__(self, encoder: Sense, staged: Any, dim: int, tag: str) -> None:
        _torch_threads(1)
        self.encoder, self.staged, self.dim, self.tag = encoder, set(staged), dim, tag

    def __call__(self, rows: pa.Table) -> pa.Table:
        todo = [r for r in rows.to_pylist() if r["id"] not in self.staged]
        if not todo:  # staged by an earlier, killed run
            return vector_table([], np.zeros((0, self.dim), np.float32), self.tag)
        return vector_table([r["id"] for r in todo], embed_rows(self.encoder, todo, self.dim),
                            self.tag)  # fmt: skip


def reembed_on_ray(
    memory: Reembeddable,
    sense: str,
    encoder: Sense,
    *,
    batch: int = REEMBED_BATCH,
    address: str | None = None,
    workers: int | None = None,
) -> ReembedReport:
    """:func:`tactus_memory.memory.reembed.reembed` with the embedding on Ray workers: staged in one
    commit (a killed job stages nothing; the re-run redoes it), swapped in one."""

    n = connect(address, workers)
    lr = _lance_ray()
    _shippable(f"encoder of sense {sense!r}", encoder)
    job = begin(memory, sense, encoder, batch)
    store = memory.store
    options = store.storage_options or None
    ds = lr.read_lance(store.items.uri, columns=["id", "raw", "text"], filter=job.redo.sql(),
                       storage_options=options, ray_remote_args={"num_cpus": 0})  # fmt: skip
    ds = ds.map_batches(_ReembedWorker, batch_size=batch, batch_format="pyarrow",
                        fn_constructor_kwargs={"encoder": encoder, "staged": sorted(job.staged),
                                               "dim": job.dim, "tag": job.tag},
                        compute=_pool(n), num_cpus=1)  # fmt: skip
    _write(lr, ds, job.table.uri, staging_schema(job.dim), options)
    job.table.checkout_latest()
    ids = job.table.search().select(["id"]).limit(None).to_arrow().column("id").to_pylist()
    job.staged.update(ids)
    return swap(memory, job, batches=1)
