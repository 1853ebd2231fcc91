"""The one settings object (pydantic-settings): what the library, the service and the CLI
can be told, from three places, highest first:

1. command-line flags and keyword arguments (``Settings(data=...)``; ``tactus serve --data``),
2. the environment, ``TACTUS_<FIELD>`` (``TACTUS_DATA=/srv/memory``, ``TACTUS_TOKEN=...``),
3. a TOML file of the same field names, named by ``--config FILE`` / ``TACTUS_CONFIG``.

``TACTUS_DATA=/srv/memory TACTUS_TOKEN=s3cret tactus serve`` equals
``tactus serve --data /srv/memory --token s3cret`` and a ``tactus.toml`` holding
``data = "/srv/memory"`` and ``token = "s3cret"`` passed as ``--config tactus.toml``.
The maintenance policy's fields (:class:`~tactus_memory.policies.MaintenanceConfig`) are
fields here too (``TACTUS_RETAIN_SECONDS``, ...); :meth:`Settings.maintenance` gives them as
the policy object the store takes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from tactus_memory.limits import DEFAULT_READ_CONSISTENCY_S, MAX_WINDOW_FRAMES, SENSE_NAME_PATTERN
from tactus_memory.policies import MaintenanceConfig, never_is_none

#: the memory every command opens when given no location (``Memory.open()``, ``tactus serve``,
#: ``tactus search``/``ingest``/..., ``make run``): ``./memory`` of the current folder, or
#: ``$TACTUS_DATA`` (the ``data`` field) where the command reads the settings
DEFAULT_MEMORY = "./memory"
#: group commit defaults (tactus_memory.memory.group_commit): 25 ms is under one 30 Hz frame period
#: (33 ms), so a glove's window never waits for more than about one frame; a 64-glove tick
#: at 30 Hz carries ~6-60 windows; 1024 pending items are ~4 s of 64 gloves at 30 Hz
DEFAULT_COMMIT_TICK_MS = 25.0
DEFAULT_COMMIT_MAX_BATCH = 256
DEFAULT_COMMIT_MAX_PENDING = 1024
#: the longest a write waits in the group commit's queue before it is refused (503 +
#: Retry-After) instead of acknowledged late (issue 48: 96 gloves at 30 Hz against one worker
#: were acknowledged a median 24 s after sending); 1 s is 30 frames of a 30 Hz glove
DEFAULT_COMMIT_MAX_WAIT_MS = 1000.0
#: niceness added to the group committer's thread (its encoder and commits) in a server: a
#: search beside a 64-glove fleet then gets the cores first (benchmarks/fleet_ii.py)
DEFAULT_COMMIT_NICE = 10


#: the most workers ``tactus serve`` starts by default: each holds its own models (~0.4 GB
#: on ONNX Runtime, docs/operations/speed.md) and appends to the one store, and issue 39's
#: capacity target is linear to 8 workers on a 16-core machine; more is asked for by name
MAX_DEFAULT_WORKERS = 8


def default_workers() -> int:
    """``tactus serve``'s default ``--workers``: the cores this process may use (its CPU
    affinity), capped at :data:`MAX_DEFAULT_WORKERS`; 2 on a 2-core machine."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(MAX_DEFAULT_WORKERS, cores))


class Settings(BaseSettings, MaintenanceConfig):
    """Everything tactus-memory can be told. Every field reads ``TACTUS_<NAME>`` too."""

    #: a field's description is the docstring under it
    model_config = SettingsConfigDict(
        env_prefix="TACTUS_", extra="ignore", use_attribute_docstrings=True
    )

    config: str | None = None
    """A TOML file of settings (these field names as keys); flags and the environment win over
    it."""

    data: str = DEFAULT_MEMORY
    """Memory location: a local directory, file://, s3://, gs:// or az:// URI."""
    space: str | None = None
    """Embedding space (registry name: minilm, qwen3vl); default: the store's recorded space,
    minilm for a fresh store."""
    space_path: str | None = None
    """Local model folder of the space (needed by Qwen3-VL-Embedding-2B)."""
    space_dim: int | None = Field(None, ge=1)
    """Matryoshka output size of a Qwen3-VL space (64..2048)."""
    touch_checkpoint: str | None = None
    """Tactus checkpoint for the touch sense (default: the shipped MiniLM one); a store in
    another space needs one trained there (tactus train --space ...)."""
    touch_senses: dict[str, str] = Field(default_factory=dict)
    """Touch senses beside the glove, each its own sensor: sense name -> Tactus checkpoint (whose
    sensor profile gives the frame shape), e.g. {skin = "/ck/skin16.safetensors"}. `tactus
    serve --touch NAME=CKPT` (repeated); env TACTUS_TOUCH_SENSES='{"skin":
    "/ck/skin16.safetensors"}'. They run on torch."""
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    token: SecretStr | None = None
    """When set, every route but the open ones (/health, /live, /ready, /, /static, /docs,
    /redoc, /openapi.json) needs 'Authorization: Bearer <token>'."""
    max_body_bytes: int = Field(16 * 1024 * 1024, ge=1024)
    """Largest request body accepted (413 beyond it)."""
    max_ws_message_bytes: int = Field(1024 * 1024, ge=1024)
    """Largest WebSocket message accepted on touch streams."""
    window: int = Field(8, ge=1, le=MAX_WINDOW_FRAMES)
    """Default frames per window on touch streams."""
    stride: int = Field(8, ge=1, le=MAX_WINDOW_FRAMES)
    """Default frames between window starts."""
    write_threads: int = Field(2, ge=1, le=64)
    """Worker threads that validate write bodies (commits: the group committer)."""
    read_threads: int = Field(8, ge=1, le=256)
    """Worker threads for reads (search, sessions); writes never take them."""
    read_consistency: float | None = Field(DEFAULT_READ_CONSISTENCY_S, ge=0.0)
    """Seconds between re-reads of the latest version (replicas sharing a store see each other's
    commits within it); off/none: never."""
    commit_tick_ms: float = Field(DEFAULT_COMMIT_TICK_MS, ge=0.0, le=1000.0)
    """Group commit: how long the oldest queued write waits for company (ms)."""
    commit_max_batch: int = Field(DEFAULT_COMMIT_MAX_BATCH, ge=1, le=100_000)
    """Group commit: most items embedded and committed at once."""
    commit_max_pending: int = Field(DEFAULT_COMMIT_MAX_PENDING, ge=1, le=1_000_000)
    """Group commit: items queued before writes are refused (503 + Retry-After)."""
    commit_max_wait_ms: float = Field(DEFAULT_COMMIT_MAX_WAIT_MS, gt=0.0, le=600_000.0)
    """Group commit: the longest a write may wait for its commit (ms); a write that waited (or
    would wait) longer is refused (503 + Retry-After; WebSocket: the error message with
    ``retry_after``) instead of acknowledged late."""
    commit_nice: int = Field(DEFAULT_COMMIT_NICE, ge=0, le=19)
    """Group commit: niceness added to the committer's thread (embedding and commits) so reads
    get the cores first under a write load; 0: the same priority."""
    encode_process: bool = False
    """Group commit: embed touch windows in a worker process of their own (its own interpreter
    lock; nice'd by commit_nice) instead of the committer's thread."""
    torch_threads: int | None = Field(None, ge=1, le=256)
    """Torch threads per call (encoder batches, query embedding). `tactus serve` defaults to half
    the CPU cores, so the committer's encoder and a search's MiniLM each get their own; unset
    elsewhere (torch's own default)."""
    touch: bool = True
    """Register the shipped touch encoder on startup when it is available."""
    onnx: str | None = None
    """Folder of ONNX exports (`tactus export-onnx`): serve MiniLM and the touch encoder on ONNX
    Runtime. `tactus serve` without it (and without `torch`) uses the default folder in the
    user's cache (MiniLM exported there on the first start)."""
    workers: int = Field(
        default_factory=default_workers,
        ge=1,
        le=64,
        description="`tactus serve`: server processes on one port and one store (each its own "
        "event loop, committer and models; worker 0 maintains). Default: the cores this "
        f"process may use, at most {MAX_DEFAULT_WORKERS}. 1: one process.",
    )
    torch: bool = False
    """`tactus serve`: run MiniLM and the touch encoder on torch instead of the default ONNX
    Runtime (a heavier, slower start; needed for spaces other than MiniLM)."""
    log_level: str = "info"

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Flags/keywords, then the environment, then the TOML file they name (if any)."""
        named = init_settings().get("config") or env_settings().get("config")
        if not named:
            return init_settings, env_settings
        if not Path(named).is_file():
            raise ValueError(f"config: no settings file at {named}")
        return init_settings, env_settings, TomlConfigSettingsSource(settings_cls, Path(named))

    @field_validator("read_consistency", mode="before")
    @classmethod
    def _never(cls, value: Any) -> Any:
        """``off``/``none``/``never``/``forever`` (or empty): never re-read (None)."""
        return never_is_none(value)

    def maintenance(self) -> MaintenanceConfig:
        """The maintenance policy these settings describe."""
        # the fields as they are (a dump would mark every field of a retention rule as set)
        return MaintenanceConfig(**{f: getattr(self, f) for f in MaintenanceConfig.model_fields})

    @field_validator("touch_senses")
    @classmethod
    def _touch_sense_names(cls, value: dict[str, str]) -> dict[str, str]:
        """Each extra touch sense: a valid sense name other than the glove's ``touch``."""
        for name, checkpoint in value.items():
            if not re.fullmatch(SENSE_NAME_PATTERN, name):
                raise ValueError(
                    f"touch sense name {name!r} must match {SENSE_NAME_PATTERN} (lower case, "
                    "digits, underscores)"
                )
            if name == "touch":
                raise ValueError(
                    "the sense 'touch' is the glove's: give its checkpoint with "
                    "--touch-checkpoint, and other touch senses other names"
                )
            if not str(checkpoint).strip():
                raise ValueError(f"touch sense {name!r} names no checkpoint")
        return value

    @field_validator("token")
    @classmethod
    def _token_not_empty(cls, value: SecretStr | None) -> SecretStr | None:
        """An empty token would lock every client out while looking like 'no token'."""
        if value is not None and not value.get_secret_value().strip():
            raise ValueError(
                "the token is empty: give a non-empty --token (or TACTUS_TOKEN), or leave it "
                "unset to serve without one"
            )
        return value

    @model_validator(mode="after")
    def _wait_bound_past_the_tick(self) -> Settings:
        """A write waits up to one tick for company: a wait bound within it refuses every write."""
        if self.commit_max_wait_ms <= self.commit_tick_ms:
            raise ValueError(
                f"commit_max_wait_ms ({self.commit_max_wait_ms:g}) must be longer than "
                f"commit_tick_ms ({self.commit_tick_ms:g})"
            )
        return self
