"""One memory per tenant behind one server: opened on a tenant's first request, each with its
own group committer; the models (the space, the live senses) are the default tenant's,
shared (:mod:`tactus_memory.storage.tenants` says where each tenant's database lives)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from tactus_memory.errors import StoreDamagedError, UnknownTenantError
from tactus_memory.identity import DEFAULT_TENANT, validate_tenant
from tactus_memory.memory.encode_process import EncoderProcess
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.memory.main import Memory
from tactus_memory.settings import Settings
from tactus_memory.storage.connect import is_remote_uri
from tactus_memory.storage.tenants import TENANTS_DIR, tenant_exists


@dataclass
class Tenant:
    """A tenant's memory and the committer its writes share."""

    name: str
    memory: Memory
    settings: Settings
    committer: GroupCommitter | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def open_committer(self) -> GroupCommitter:
        """The running group committer (a new one after a shutdown closed the last)."""
        with self._lock:
            if self.committer is None or self.committer.closed:
                encoder = None
                if self.settings.encode_process:
                    encoder = EncoderProcess(
                        ("touch",),
                        nice=self.settings.commit_nice,
                        threads=self.settings.torch_threads,
                    )
                self.committer = GroupCommitter(
                    self.memory,
                    tick=self.settings.commit_tick_ms / 1000.0,
                    max_batch=self.settings.commit_max_batch,
                    max_pending=self.settings.commit_max_pending,
                    max_wait=self.settings.commit_max_wait_ms / 1000.0,
                    # torch threads; an ONNX server never imports torch
                    encode_threads=None if self.settings.onnx else self.settings.torch_threads,
                    nice=self.settings.commit_nice,
                    encoder=encoder,
                )
            return self.committer


class Tenants:
    """name -> :class:`Tenant`; the default one is the memory the app was made with. Only
    tenants that exist are opened (``storage.tenants.tenant_exists``): ``named`` gives the
    tenants the store's keys name."""

    def __init__(
        self, default: Memory, settings: Settings, named: Callable[[], Iterable[str]] = tuple
    ) -> None:
        self.default = default
        self.settings = settings
        self.named = named
        self._tenants = {DEFAULT_TENANT: Tenant(DEFAULT_TENANT, default, settings)}
        self._lock = threading.Lock()

    def get(self, name: str) -> Tenant:
        """The tenant ``name`` (its memory opened on first use); UnknownTenantError (404) for
        a tenant that does not exist, which is never created here."""
        found = self._tenants.get(name)
        if found is not None:
            why = self.missing(found)
            if why is not None:
                raise StoreDamagedError(why)
            return found
        base = self.default.store
        if not tenant_exists(base.uri, name, self.named(), base.storage_options or None):
            raise UnknownTenantError(
                f"no tenant {name!r}: a tenant comes into being with its first key "
                "(tactus keys create --tenant NAME)"
            )
        with self._lock:
            if name not in self._tenants:
                self._tenants[name] = Tenant(name, self._open(name), self.settings)
            return self._tenants[name]

    @staticmethod
    def missing(tenant: Tenant) -> str | None:
        """Why an opened tenant's database is gone (its local folder was removed under the
        running server), else None: a 503 naming the tenant, not a 500 on the next read.
        Object stores are not checked here (a listing per request); their reads fail as a
        store failure (503) anyway."""
        uri = tenant.memory.store.uri
        if tenant.name == DEFAULT_TENANT or is_remote_uri(uri) or os.path.isdir(uri):
            return None
        return (
            f"tenant {tenant.name!r}: its folder ({TENANTS_DIR}/{tenant.name}) is gone from the "
            "store; restore it from a backup (nothing is answered or written until then)"
        )

    def _open(self, name: str) -> Memory:
        base = self.default.store
        memory = Memory.open(
            base.uri,
            self.default.space,
            tenant=validate_tenant(name),
            storage_options=base.storage_options or None,
            read_consistency_interval=base.read_consistency,
            index=base.index,
            maintenance=base.maintenance,
            background=self.default.background,
        )
        for sense_name, sense in self.default.senses.items():  # shared live senses
            if sense_name not in memory.senses:
                memory.add_sense(sense)
        return memory

    def __iter__(self) -> Iterator[Tenant]:
        return iter(list(self._tenants.values()))
