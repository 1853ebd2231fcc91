"""API keys: per tenant, with a scope, stored hashed in the store's root database.

A key reads ``tk_<key id>_<secret>``; the table ``keys`` keeps its id, tenant, scope, session
prefix (``--sessions``), expiry, revocation and last use, and the secret's scrypt hash (a slow
KDF, standard library; never the key). Every replica reads the same table, so a key created
or revoked on one is seen by the others within the read consistency interval
(:mod:`tactus_memory.storage.connect`): a verifier re-reads the table at most that often, and
checks a presented key's scrypt hash once per process (then a SHA-256 of it is remembered, so
a request costs a dictionary lookup).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from tactus_memory.errors import (
    InvalidInputError,
    NotFoundError,
    StoreDamagedError,
    ThrottledError,
)
from tactus_memory.identity import validate_tenant
from tactus_memory.names import validate_id
from tactus_memory.storage.connect import normalise_uri, storage_options_for
from tactus_memory.storage.integrity import _lance_message
from tactus_memory.storage.tables import keys_schema
from tactus_memory.where import _sql_str, validate_session_prefix

log = logging.getLogger(__name__)

#: the key table, in the root database
KEYS = "keys"
#: scopes, weakest first: read (searches, reads), write (adds items), admin (deletes, keys)
SCOPES = ("read", "write", "admin")
#: scrypt cost (RFC 7914: N=2^14, r=8, p=1 is the interactive-login setting; ~0.1 s here)
SCRYPT = {"n": 2**14, "r": 8, "p": 1, "dklen": 32}
#: how a key starts (so a leaked one is recognisable in logs and scanners)
KEY_PREFIX = "tk_"
#: a key's last use is written back at most this often (seconds): not a commit per request
LAST_USED_EVERY = 60.0
#: presented keys whose scrypt check passed, remembered per process (by SHA-256)
VERIFIED_CACHE = 4096
#: secret checks per key id and second, at most, counting those that failed and those under
#: way (each costs one scrypt; a check that passes gives its slot back): beyond that a
#: presented key of that id, right or wrong, is answered ThrottledError (429 +
#: Retry-After) unchecked until the second is over, never refused as wrong
FAILED_CHECKS_PER_S = 5


def check_scope(scope: str) -> str:
    if scope not in SCOPES:
        raise InvalidInputError(f"unknown scope {scope!r}: use one of {', '.join(SCOPES)}")
    return scope


def allows(have: str, need: str) -> bool:
    """Whether a key of scope ``have`` may do what needs ``need`` (admin > write > read)."""
    return SCOPES.index(check_scope(have)) >= SCOPES.index(check_scope(need))


def _hash(secret: str, salt: bytes) -> bytes:
    return hashlib.scrypt(secret.encode(), salt=salt, **SCRYPT)


@dataclass(frozen=True)
class KeyInfo:
    """One key as listed (never the key itself)."""

    key_id: str
    tenant: str
    scope: str
    created: float
    expires: float | None
    revoked: float | None
    last_used: float | None
    #: the key sees only sessions whose id starts with this (None: every session)
    sessions: str | None = None

    def live(self, now: float) -> bool:
        return self.revoked is None and (self.expires is None or now < self.expires)


class KeyStore:
    """The ``keys`` table of the store at ``root`` (created on the first key)."""

    def __init__(
        self,
        root: str,
        *,
        storage_options: dict[str, str] | None = None,
        refresh: float = 1.0,
    ) -> None:
        """``refresh``: seconds between re-reads of the table (the read consistency)."""
        import lancedb

        self.uri = normalise_uri(str(root))
        options = storage_options_for(self.uri, storage_options)
        self.db = lancedb.connect(
            self.uri, storage_options=options or None, read_consistency_interval=None
        )
        self.refresh = refresh
        self._table: Any = None
        self._rows: dict[str, dict[str, Any]] = {}
        self._read_at = -float("inf")
        self._lock = threading.Lock()
        self._verified: OrderedDict[bytes, str] = OrderedDict()
        self._used: dict[str, float] = {}
        #: the throttle's clock (seconds, monotonic)
        self.clock = time.monotonic
        #: key id -> (the second, checks in it that failed or are under way)
        self._failed: dict[str, tuple[int, int]] = {}

    # ----------------------------------------------------------- table
    def _open(self, create: bool = False) -> Any:
        if self._table is None:
            res = self.db.list_tables()
            if KEYS in set(getattr(res, "tables", res)):
                self._table = self.db.open_table(KEYS)
            elif create:
                self._table = self.db.create_table(KEYS, schema=keys_schema(), exist_ok=True)
        return self._table

    def _read(self, force: bool = False) -> dict[str, dict[str, Any]]:
        """key id -> row, re-read when older than ``refresh`` seconds."""
        with self._lock:
            if not force and time.monotonic() - self._read_at < self.refresh:
                return self._rows
            try:
                table = self._open()
                if table is not None:
                    table.checkout_latest()
                    rows = table.search().limit(None).to_arrow().to_pylist()
                    self._rows = {r["key_id"]: r for r in rows}
            except Exception as exc:  # noqa: BLE001  (no key can be checked: say so, 503)
                raise StoreDamagedError(
                    "the store's keys table cannot be read, so no key can be checked "
                    f"({_lance_message(exc, self.uri)}); restore it from a backup"
                ) from exc
            self._read_at = time.monotonic()
            return self._rows

    def any_keys(self) -> bool:
        """Whether the store has any key (then every request must present one)."""
        return bool(self._read())

    def tenants(self) -> set[str]:
        """The tenants the keys name (revoked and expired ones included)."""
        return {row["tenant"] for row in self._read().values()}

    # ----------------------------------------------------------- changes
    def create(
        self,
        tenant: str,
        scope: str = "read",
        expires_days: float | None = None,
        *,
        sessions: str | None = None,
    ) -> tuple[str, str]:
        """A new key for ``tenant`` with ``scope`` (limited to the sessions whose id starts
        with ``sessions`` when given): returns (key id, the key). The key is shown this once:
        only its hash is stored. The first key naming a tenant brings the tenant into being
        (:func:`tactus_memory.storage.tenants.tenant_exists`)."""
        import pyarrow as pa

        tenant, scope = validate_tenant(tenant), check_scope(scope)
        if sessions is not None:
            sessions = validate_session_prefix(sessions)
        if expires_days is not None and not expires_days > 0:
            raise InvalidInputError(f"--expires must be > 0 days, got {expires_days!r}")
        key_id, secret, salt = (
            secrets.token_hex(6),
            secrets.token_urlsafe(32),
            secrets.token_bytes(16),
        )
        now = time.time()
        row = {
            "key_id": key_id,
            "tenant": tenant,
            "scope": scope,
            "salt": salt,
            "hash": _hash(secret, salt),
            "created": now,
            "expires": None if expires_days is None else now + float(expires_days) * 86400.0,
            "revoked": None,
            "last_used": None,
            "sessions": sessions,
        }
        self._open(create=True).add(pa.Table.from_pylist([row], schema=keys_schema()))
        self._read(force=True)
        return key_id, f"{KEY_PREFIX}{key_id}_{secret}"

    def revoke(self, key_id: str) -> KeyInfo:
        """Mark a key revoked (NotFoundError for an unknown id); it stops working on every
        replica within the read consistency interval."""
        key_id = validate_id(key_id, "key id")
        table = self._open()
        row = self._read(force=True).get(key_id)
        if table is None or row is None:
            raise NotFoundError(f"no key with id {key_id!r}")
        if row["revoked"] is None:
            table.update(where=f"key_id = {_sql_str(key_id)}", values={"revoked": time.time()})
        return self._info(self._read(force=True)[key_id])

    def list(self) -> list[KeyInfo]:
        """Every key, oldest first (ids, tenants, scopes, times: never a key or its hash)."""
        rows = sorted(self._read(force=True).values(), key=lambda r: r["created"])
        return [self._info(r) for r in rows]

    @staticmethod
    def _info(row: dict[str, Any]) -> KeyInfo:
        return KeyInfo(**{f: row.get(f) for f in KeyInfo.__dataclass_fields__})  # type: ignore[arg-type]  # the record's columns

    # ----------------------------------------------------------- checks
    def verify(self, presented: str) -> KeyInfo | None:
        """The live key ``presented`` is (its record), or None: unknown, wrong, revoked or
        expired (all alike to the caller). ThrottledError (429) when its key id has had
        :data:`FAILED_CHECKS_PER_S` checks this second, before any check of this one."""
        if not presented.startswith(KEY_PREFIX):
            return None
        key_id, _, secret = presented[len(KEY_PREFIX) :].partition("_")
        row = self._read().get(key_id)
        if row is None or not secret:
            return None
        digest = hashlib.sha256(presented.encode()).digest()
        with self._lock:
            known = self._verified.get(digest) == key_id
        if not known:
            second = self._reserve(key_id)
            if not hmac.compare_digest(_hash(secret, row["salt"]), row["hash"]):
                return None  # the reserved slot stays taken: a failure this second
            with self._lock:
                at, used = self._failed.get(key_id, (second, 0))
                if at == second and used > 0:  # a right secret gives its slot back
                    self._failed[key_id] = (at, used - 1)
                self._verified[digest] = key_id
                while len(self._verified) > VERIFIED_CACHE:
                    self._verified.popitem(last=False)
        info = self._info(row)
        now = time.time()
        if not info.live(now):
            return None
        self._touch(key_id, now)
        return info

    def _reserve(self, key_id: str) -> int:
        """Take one of this second's :data:`FAILED_CHECKS_PER_S` check slots of ``key_id``
        (checked and taken under one lock, so no number of threads gets more); returns the
        second. ThrottledError when none is left."""
        now = self.clock()
        second = int(now)
        with self._lock:
            at, used = self._failed.get(key_id, (second, 0))
            used = used if at == second else 0
            if used >= FAILED_CHECKS_PER_S:
                raise ThrottledError(
                    f"too many key checks for key id {key_id!r} this second "
                    f"(at most {FAILED_CHECKS_PER_S}): retry after a second",
                    retry_after=max(0.001, second + 1 - now),
                )
            self._failed[key_id] = (second, used + 1)
        return second

    def _touch(self, key_id: str, now: float) -> None:
        """Write the key's last use back, at most every :data:`LAST_USED_EVERY` seconds."""
        with self._lock:
            if now - self._used.get(key_id, -float("inf")) < LAST_USED_EVERY:
                return
            self._used[key_id] = now
        try:
            self._table.update(where=f"key_id = {_sql_str(key_id)}", values={"last_used": now})
        except Exception as exc:  # noqa: BLE001  (bookkeeping: the request goes on)
            log.warning("could not record the last use of key %s: %s", key_id, exc)
