"""Dependencies shared by the routers (``Annotated`` aliases, FastAPI style)."""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Path, Request
from starlette.requests import HTTPConnection

from tactus_memory.service.problems import ServiceUnavailable
from tactus_memory.service.settings import Settings
from tactus_memory.service.writes import Writer

#: session and item ids: the store's rule (tactus_memory.store.ID_RE), checked at the edge
ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$"
ID_DESCRIPTION = "1-128 characters of [A-Za-z0-9._:-], starting with a letter or digit."


@dataclass
class ServiceState:
    """What the app holds: the settings, the memory, and why touch is off (if it is)."""

    settings: Settings
    memory: Any
    touch_unavailable: str | None = None
    writer: Writer | None = None
    #: the store's directory cannot be written: write routes answer 503 (reads still work)
    read_only: bool = False
    #: the space has been warmed up (the lifespan ran): ``/ready`` answers 200
    warm: bool = False

    def __post_init__(self) -> None:
        if self.writer is None:
            self.writer = Writer(self.settings.write_threads)


def get_state(conn: HTTPConnection) -> ServiceState:
    return conn.app.state.tactus


def get_settings(state: Annotated[ServiceState, Depends(get_state)]) -> Settings:
    return state.settings


def get_memory(state: Annotated[ServiceState, Depends(get_state)]) -> Any:
    return state.memory


def get_writer(state: Annotated[ServiceState, Depends(get_state)]) -> Writer:
    return state.writer


StateDep = Annotated[ServiceState, Depends(get_state)]
WriterDep = Annotated[Writer, Depends(get_writer)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
#: the ``tactus_memory.memory.Memory`` behind the app
MemoryDep = Annotated[Any, Depends(get_memory)]
SessionId = Annotated[
    str,
    Path(
        pattern=ID_PATTERN,
        max_length=128,
        description="Session id. " + ID_DESCRIPTION,
        examples=["kitchen-2026-11-21"],
    ),
]


def token_ok(settings: Settings, presented: str | None) -> bool:
    """Constant-time check of a presented token (True when no token is configured)."""
    if settings.token is None:
        return True
    if not presented:
        return False
    expected = settings.token.get_secret_value().encode()
    return hmac.compare_digest(presented.encode(), expected)


def bearer(authorization: str | None) -> str | None:
    if not authorization:
        return None
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return None
    return value.strip()


def require_token(request: Request, settings: SettingsDep) -> None:
    """Every HTTP route but /health: ``Authorization: Bearer <token>`` when a token is set."""
    if settings.token is None:
        return
    if not token_ok(settings, bearer(request.headers.get("authorization"))):
        raise HTTPException(
            401,
            "missing or wrong bearer token: send 'Authorization: Bearer <token>'",
            headers={"WWW-Authenticate": 'Bearer realm="tactus"'},
        )


def require_touch(state: StateDep) -> None:
    """Touch routes answer 503 when no touch sense is registered, naming why."""
    memory = state.memory
    if "touch" not in memory.senses:
        why = state.touch_unavailable or "no sense named 'touch' is registered in this memory"
        raise ServiceUnavailable(f"touch is not available on this server: {why}")


Authorized = Depends(require_token)
TouchAvailable = Depends(require_touch)
