"""Service settings: environment variables with the ``TACTUS_`` prefix (pydantic-settings).

``TACTUS_DATA=/srv/memory TACTUS_TOKEN=s3cret tactus serve`` equals
``tactus serve --data /srv/memory --token s3cret``; command-line flags win over the environment.
"""

from __future__ import annotations

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from tactus_memory.connect import DEFAULT_MEMORY
from tactus_memory.limits import MAX_WINDOW_FRAMES


class Settings(BaseSettings):
    """Everything the service can be told. Every field reads ``TACTUS_<NAME>`` too."""

    model_config = SettingsConfigDict(env_prefix="TACTUS_", extra="ignore")

    data: str = Field(
        DEFAULT_MEMORY,
        description="Memory location: a local directory, file://, s3://, gs:// or az:// URI.",
    )
    space: str | None = Field(
        None,
        description="Embedding space (registry name: minilm, qwen3vl); default: the store's "
        "recorded space, minilm for a fresh store.",
    )
    space_path: str | None = Field(
        None, description="Local model folder of the space (needed by Qwen3-VL-Embedding-2B)."
    )
    space_dim: int | None = Field(
        None, ge=1, description="Matryoshka output size of a Qwen3-VL space (64..2048)."
    )
    touch_checkpoint: str | None = Field(
        None,
        description="Tactus checkpoint for the touch sense (default: the shipped MiniLM one); "
        "a store in another space needs one trained there (tactus train --space ...).",
    )
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    token: SecretStr | None = Field(
        None,
        description="When set, every route but the open ones (/health, /live, /ready, /, "
        "/static, /docs, /redoc, /openapi.json) needs 'Authorization: Bearer <token>'.",
    )
    max_body_bytes: int = Field(
        16 * 1024 * 1024, ge=1024, description="Largest request body accepted (413 beyond it)."
    )
    max_ws_message_bytes: int = Field(
        1024 * 1024, ge=1024, description="Largest WebSocket message accepted on touch streams."
    )
    window: int = Field(
        8, ge=1, le=MAX_WINDOW_FRAMES, description="Default frames per window on touch streams."
    )
    stride: int = Field(
        8, ge=1, le=MAX_WINDOW_FRAMES, description="Default frames between window starts."
    )
    write_threads: int = Field(
        2,
        ge=1,
        le=64,
        description="Worker threads that validate write bodies (commits: the group committer).",
    )
    read_threads: int = Field(
        8,
        ge=1,
        le=256,
        description="Worker threads for reads (search, sessions); writes never take them.",
    )
    commit_tick_ms: float = Field(
        25.0,
        ge=0.0,
        le=1000.0,
        description="Group commit: how long the oldest queued write waits for company (ms).",
    )
    commit_max_batch: int = Field(
        256,
        ge=1,
        le=100_000,
        description="Group commit: most items embedded and committed at once.",
    )
    commit_max_pending: int = Field(
        1024,
        ge=1,
        le=1_000_000,
        description="Group commit: items queued before writes are refused (503 + Retry-After).",
    )
    torch_threads: int | None = Field(
        None,
        ge=1,
        le=256,
        description="Torch threads per call (encoder batches, query embedding). `tactus serve` "
        "defaults to half the CPU cores, so the committer's encoder and a search's MiniLM each "
        "get their own; unset elsewhere (torch's own default).",
    )
    touch: bool = Field(
        True, description="Register the shipped touch encoder on startup when it is available."
    )
    log_level: str = "info"
    maintain: bool = Field(
        True,
        description="This server maintains the store (compaction, cleanup). Replicas sharing "
        "a store run with maintain=False (`--no-maintain`) beside one `tactus maintain`.",
    )

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
