"""Service settings: environment variables with the ``TACTUS_`` prefix (pydantic-settings).

``TACTUS_DATA=/srv/memory TACTUS_TOKEN=s3cret tactus serve`` equals
``tactus serve --data /srv/memory --token s3cret``; command-line flags win over the environment.
"""

from __future__ import annotations

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Everything the service can be told. Every field reads ``TACTUS_<NAME>`` too."""

    model_config = SettingsConfigDict(env_prefix="TACTUS_", extra="ignore")

    data: str = Field(
        "./tactus-memory",
        description="Memory location: a local directory, file://, s3://, gs:// or az:// URI.",
    )
    space: str = Field("minilm", description="Embedding space for a fresh store (registry name).")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    token: SecretStr | None = Field(
        None, description="When set, every route but /health needs 'Authorization: Bearer <token>'."
    )
    max_body_bytes: int = Field(
        16 * 1024 * 1024, ge=1024, description="Largest request body accepted (413 beyond it)."
    )
    max_ws_message_bytes: int = Field(
        1024 * 1024, ge=1024, description="Largest WebSocket message accepted on touch streams."
    )
    window: int = Field(8, ge=1, le=512, description="Default frames per window on touch streams.")
    stride: int = Field(8, ge=1, le=512, description="Default frames between window starts.")
    write_threads: int = Field(
        2, ge=1, le=64, description="Worker threads for writes (commits are serialised)."
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
