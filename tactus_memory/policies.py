"""The operator's policies for a store: maintenance (compaction, cleanup, orphan removal) and
retention (expiry, thinning). Fields only: :class:`tactus_memory.settings.Settings` reads
them from the environment or the settings file, and storage applies them
(:mod:`tactus_memory.storage.compaction`, :mod:`tactus_memory.storage.retention`), so both
import them from here rather than from each other.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from tactus_memory.limits import ID_RE
from tactus_memory.names import validate_id, validate_sense_name

MiB = 1024 * 1024

#: Seconds an unreferenced file is kept before it counts as a crashed writer's: longer than
#: any write transaction could take (the largest compaction merges at most
#: ``max_merge_share`` of a table; an ANN index build on a large table on 2 cores takes
#: minutes to tens of minutes), with a wide margin. Erasure after a crash waits this long.
ORPHAN_GRACE_S = 6 * 3600.0

#: the cosine bar of thinning, measured on STAG (weights_lite + blindfolded_lite_train,
#: the shipped checkpoint, the service's windows): 60 % of adjacent windows of a hand held
#: still reach it, 0.9 % of a hand moving and 0.04 % of pairs of grasps of different objects;
#: MiniLM: every exact text repeat, 1 in 4 reworded repeats, no pair of different events
#: (benchmarks/thinning.py, benchmarks/results/thinning.json)
THIN_COSINE = 0.985
#: what a setting may say for "no limit" (TOML has no null)
NEVER = frozenset({"none", "never", "forever", "off", ""})


def never_is_none(value: Any) -> Any:
    """``none``/``never``/``forever``/``off`` (any case) or an empty string -> None."""
    return None if isinstance(value, str) and value.strip().lower() in NEVER else value


class RetentionRule(BaseModel):
    """Retention for part of the store: every key given must match (tenant name, session id
    or ``prefix*``, sense name); the policy fields it sets override the store-wide ones
    (``retain_days: null`` keeps forever)."""

    model_config = ConfigDict(extra="forbid")

    tenant: str | None = Field(None, description="Tenant name (a store opened for it).")
    session: str | None = Field(None, description="Session id, or a prefix ending in '*'.")
    sense: str | None = Field(None, description="Sense name.")
    retain_days: float | None = Field(None, gt=0.0, description="Expire after this many days.")
    thin_after_days: float | None = Field(
        None, ge=0.0, description="Thin stale duplicates older than this many days."
    )
    thin_cosine: float | None = Field(None, gt=0.0, le=1.0, description="Thinning's bar.")

    _no_limit = field_validator("retain_days", "thin_after_days", mode="before")(
        classmethod(lambda cls, v: never_is_none(v))
    )

    @field_validator("tenant")
    @classmethod
    def _tenant(cls, value: str | None) -> str | None:
        return None if value is None else validate_id(value, "tenant")

    @field_validator("session")
    @classmethod
    def _session(cls, value: str | None) -> str | None:
        if value is None:
            return None
        body = value[:-1] if value.endswith("*") else value
        if value != "*" and not ID_RE.match(body):
            raise ValueError(f"session must be a session id or a prefix ending in '*': {value!r}")
        return value

    @field_validator("sense")
    @classmethod
    def _sense(cls, value: str | None) -> str | None:
        return None if value is None else validate_sense_name(value)

    def matches(self, tenant: str | None, session: str, sense: str) -> bool:
        if self.tenant is not None and self.tenant != tenant:
            return False
        if self.sense is not None and self.sense != sense:
            return False
        if self.session is None:
            return True
        if self.session.endswith("*"):
            return session.startswith(self.session[:-1])
        return session == self.session

    def specificity(self) -> int:
        exact = self.session is not None and not self.session.endswith("*")
        prefix = self.session is not None and not exact
        return 8 * exact + 4 * prefix + 2 * (self.sense is not None) + (self.tenant is not None)


class MaintenanceConfig(BaseModel):
    """The maintenance policy. Its fields are settings too (``TACTUS_<NAME>``, see
    :class:`tactus_memory.settings.Settings`, whose ``maintenance()`` builds one). Each
    field's description is the docstring under it."""

    model_config = ConfigDict(use_attribute_docstrings=True)

    maintain: bool = True
    """This process maintains the store (compaction, index refresh, cleanup). Exactly one process
    per store should: replicas run with maintain=False."""
    retain_seconds: float = Field(30.0, ge=0.0)
    """Keep a version until it has been superseded this long (readers in flight finish within it;
    other replicas re-read the latest version every read_consistency)."""
    maintain_interval: float = Field(10.0, gt=0.0)
    """Seconds between passes of `tactus maintain`."""
    cleanup_interval: float = Field(10.0, ge=0.0)
    """Least seconds between version cleanups (each reads every kept manifest, so it runs in its
    own thread, not on every compaction)."""
    fan_in: int = Field(8, ge=2)
    """Merge a tier once it has this many adjacent fragments."""
    tier_base_bytes: int = Field(1 * MiB, ge=1)
    """Fragments below this are tier 0 (the streaming tail)."""
    settled_bytes: int = Field(512 * MiB, ge=1)
    """Fragments of this size are never merged again."""
    max_merge_share: float = Field(0.25, gt=0.0, le=1.0)
    """A merge rewrites at most this share of the table (or free_merge_bytes): its inputs stay on
    disk for retain_seconds, so this bounds the disk spike."""
    free_merge_bytes: int = Field(16 * MiB, ge=0)
    """Merges up to this size are allowed whatever the share."""
    deletion_threshold: float = Field(0.1, gt=0.0, le=1.0)
    """Rewrite a fragment alone once this share is deleted."""
    num_threads: int = Field(1, ge=1)
    """Threads per compaction (2 cores: leave 1)."""
    erase_deleted: bool = True
    """Rewrite every fragment holding deleted rows (not only past deletion_threshold), so
    deleted, expired and thinned data leave the store's files once cleanup removes the
    versions that still name them (after retain_seconds)."""
    orphan_grace_seconds: float = Field(ORPHAN_GRACE_S, ge=0.0)
    """Remove a data, deletion or index file no version references once it is this old (a crashed
    writer's; younger ones may be a writer's mid-commit)."""
    # retention (tactus_memory.storage.retention; docs/operations/retention.md)
    retain_days: float | None = Field(None, gt=0.0)
    """Delete items written more than this many days ago (none: keep)."""
    thin_after_days: float | None = Field(None, ge=0.0)
    """Thin stale duplicates among items older than this (none: off)."""
    thin_cosine: float = Field(THIN_COSINE, gt=0.0, le=1.0)
    """Thinning's bar: cosine to a kept neighbour."""
    retention: list[RetentionRule] = Field(default_factory=list)
    """Rules per tenant, session (id or prefix*) and/or sense overriding retain_days,
    thin_after_days, thin_cosine (the most specific rule wins)."""
    retention_interval: float = Field(600.0, ge=0.0)
    """Least seconds between retention passes (expiry, thinning)."""

    @field_validator("retain_days", "thin_after_days", mode="before")
    @classmethod
    def _no_limit(cls, value: Any) -> Any:
        return never_is_none(value)
