"""Live touch: WebSocket ``/sessions/{session}/touch/stream``, frames in, stored windows out.

Protocol (all server messages are JSON objects with a ``type``):

* connect with optional query parameters ``window`` (K, frames per window), ``stride``
  (frames between window starts; ``stride > window`` skips frames), ``calibrated``
  (frames already calibrated; default false = raw sensor units), ``hz`` and ``t0`` (times
  for binary frames: frame i gets ``t0 + i / hz``; without ``hz`` the server clock), and
  ``token`` (or an ``Authorization: Bearer`` header) when the server has a token.
* the server answers ``{"type": "ready", "window": K, "stride": S, ...}`` (with
  ``--workers N``, also ``"worker": i``, the process that holds the connection).
* send frames one by one: text ``{"frame": [[...32] x 32], "t": 12.5}``, or binary ``.npy``
  bytes of a (32, 32) frame, or of (N, 32, 32) frames (parsed, timed and windowed as one
  array).
* every full window is stored (``t`` = first frame's t, ``t_end`` = last frame's t, source =
  this stream's id) and acknowledged after its commit:
  ``{"type": "stored", "id": "...", "seq": n, "t": ..., "t_end": ...}``.
* a bad frame gets ``{"type": "error", "error": {problem details}, "frame": i}`` and is
  skipped; a window the touch sense refuses (e.g. values already in [0, 1] on a raw stream)
  gets ``{"type": "error", "error": {...}, "windows": [seq]}``. The connection stays open.
  A partial window left at disconnect is not stored.
* when the server's write queue is full the window is refused, not stored:
  ``{"type": "error", "error": {status 503...}, "windows": [seq], "retry_after": 1.0}``.
* an idle window (no contact: the touch sense refuses it, ``tactus_memory.touch.windows``) is
  not stored (an idle hand must never match "holding a ..."):
  ``{"type": "idle", "seq": n, "t": ..., "t_end": ...}``.

Each window is validated on arrival and handed to the service's group committer
(``tactus_memory.memory.group_commit``): the windows of every glove and the HTTP writes that arrive
within
one tick are embedded in one encoder call and stored in one commit. An ack task per
connection sends the ``stored`` messages in order, each after its commit; at most
``QUEUE_WINDOWS`` windows per connection wait for their commit, beyond that the receive loop
stops reading (TCP pushes back on the glove).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
import uuid
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, WebSocket, WebSocketDisconnect

from tactus_memory.errors import IdleWindowError, InvalidInputError, OverloadedError, TactusError
from tactus_memory.limits import MAX_WINDOW_FRAMES
from tactus_memory.service.arrays import as_frame, load_npy, loads_strict
from tactus_memory.service.deps import (
    PrincipalDep,
    SessionId,
    SettingsDep,
    StateDep,
    TenantDep,
    TouchAvailable,
    Writable,
)
from tactus_memory.service.problems import problem_body, problem_for_exception
from tactus_memory.touch.profile import FRAME_SHAPE
from tactus_memory.touch.windows import WindowStream

log = logging.getLogger("tactus_memory.service")

router = APIRouter(tags=["touch"])

QUEUE_WINDOWS = 256


class StreamParams:
    """The connection's query parameters, validated (InvalidInputError names the bad one)."""

    def __init__(self, query: Any, default_window: int, default_stride: int) -> None:
        self.window = self._int(query, "window", default_window)
        self.stride = self._int(query, "stride", default_stride)
        self.calibrated = self._bool(query, "calibrated")
        hz = query.get("hz")
        self.hz = None if hz is None else self._float(hz, "hz")
        if self.hz is not None and self.hz <= 0:
            raise InvalidInputError(f"hz must be positive, got {hz!r}")
        self.t0 = self._float(query.get("t0", "0"), "t0")

    @staticmethod
    def _int(query: Any, name: str, default: int) -> int:
        raw = query.get(name)
        if raw is None:
            return default
        try:
            value = int(raw)
        except ValueError:
            raise InvalidInputError(f"{name} must be an integer, got {raw!r}") from None
        if not 1 <= value <= MAX_WINDOW_FRAMES:
            raise InvalidInputError(f"{name} must be in [1, {MAX_WINDOW_FRAMES}], got {value}")
        return value

    @staticmethod
    def _bool(query: Any, name: str) -> bool:
        raw = str(query.get(name, "false")).lower()
        if raw not in ("true", "false", "1", "0", "yes", "no"):
            raise InvalidInputError(f"{name} must be true or false, got {raw!r}")
        return raw in ("true", "1", "yes")

    @staticmethod
    def _float(raw: str, name: str) -> float:
        try:
            value = float(raw)
        except ValueError:
            raise InvalidInputError(f"{name} must be a number, got {raw!r}") from None
        if not math.isfinite(value):
            raise InvalidInputError(f"{name} must be finite, got {raw!r}")
        return value


def _frame_time(obj: Any, index: int) -> float:
    if "t" not in obj:
        raise InvalidInputError(f"frame message {index} has no 't'")
    t = obj["t"]
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
        raise InvalidInputError(f"frame message {index}: 't' must be a finite number, got {t!r}")
    return float(t)


def stream_params(websocket: WebSocket, settings: SettingsDep) -> StreamParams:
    """The connection's query parameters (a bad one refuses the socket: 422, 1008)."""
    return StreamParams(websocket.query_params, settings.window, settings.stride)


@router.websocket(
    "/sessions/{session}/touch/stream", name="touch_stream", dependencies=[Writable, TouchAvailable]
)
async def touch_stream(
    websocket: WebSocket,
    session: SessionId,
    state: StateDep,
    tenant: TenantDep,
    principal: PrincipalDep,
    params: Annotated[StreamParams, Depends(stream_params)],
) -> None:
    """The token, the session id, a writable store and the touch sense are checked by the
    same dependencies as the HTTP routes (the app includes this router with the token)."""
    send_lock = asyncio.Lock()

    async def send(message: dict[str, Any]) -> None:
        async with send_lock:
            await websocket.send_text(json.dumps(message))

    await websocket.accept()

    stream_id = "ws-" + uuid.uuid4().hex[:16]
    # the library's stream windowing, without a profile: the touch sense calibrates each
    # window once (its own profile) and refuses an idle one (IdleWindowError)
    windower = WindowStream(params.window, params.stride, profile=None)
    # windows handed to the group committer, waiting for their commit (bounded: when full,
    # the receive loop stops reading and TCP pushes back on the glove)
    acks: asyncio.Queue[tuple[int, float, float, asyncio.Future[list[str]]] | None]
    acks = asyncio.Queue(QUEUE_WINDOWS)
    await send(
        {
            "type": "ready",
            "session": session,
            "stream": stream_id,
            "window": params.window,
            "stride": params.stride,
            "calibrated": params.calibrated,
            # `tactus serve --workers N`: which worker process holds this glove
            **({"worker": state.workers.index} if state.workers is not None else {}),
        }
    )

    async def acker() -> None:
        """Acknowledge windows in order, each after the group commit that stored it."""
        while True:
            entry = await acks.get()
            if entry is None:
                return
            seq, t_first, t_last, fut = entry
            try:
                ids = await fut
            except Exception as exc:  # noqa: BLE001  (report, keep the stream alive)
                await _try_send(send, _window_error(exc, seq, stream_id))
                continue
            stored[0] += 1
            await _try_send(
                send, {"type": "stored", "id": ids[0], "seq": seq, "t": t_first, "t_end": t_last}
            )

    stored = [0]  # windows committed, for the audit log

    acker_task = asyncio.create_task(acker())
    frame_index = 0
    seq = 0
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            try:
                frames, times = _parse(
                    message, frame_index, params, state.settings.max_ws_message_bytes
                )
            except TactusError as exc:
                await send(
                    {"type": "error", "error": problem_for_exception(exc), "frame": frame_index}
                )
                frame_index += 1
                continue
            # every frame of the message in one push (one numpy operation, not one per frame)
            frame_index += len(frames)
            done = windower.push(frames, times)
            for win, t_first, t_last in zip(done.frames, done.t, done.t_end, strict=True):
                try:  # the sense's own checks (range, calibration, idle), before queueing
                    queued = tenant.open_committer().submit(  # the one library write call
                        session,
                        "touch",
                        [win],
                        t=[float(t_first)],
                        t_end=[float(t_last)],
                        source=stream_id,
                        options={"calibrated": params.calibrated},
                        skip_idle=False,  # one window: an "idle" ack, below
                    )
                    fut = asyncio.wrap_future(queued)
                except IdleWindowError:  # no contact: never stored as a grasp
                    span = {"t": float(t_first), "t_end": float(t_last)}
                    await send({"type": "idle", "seq": seq, **span})
                except TactusError as exc:  # invalid window, or the write queue is full
                    await send(_window_error(exc, seq, stream_id))
                else:
                    await acks.put((seq, float(t_first), float(t_last), fut))
                seq += 1
            if acker_task.done():
                break
    except WebSocketDisconnect:
        pass
    finally:
        try:
            acks.put_nowait(None)
        except asyncio.QueueFull:
            await acks.put(None)
        with contextlib.suppress(Exception):
            await acker_task
        if state.audit is not None:
            route = "WS /sessions/{session}/touch/stream"
            state.audit.record(principal.key_id, principal.tenant, route, 101, stored[0])
    with contextlib.suppress(Exception):
        await websocket.close()


def _window_error(exc: BaseException, seq: int, stream_id: str) -> dict[str, Any]:
    """The error message for window ``seq``: the problem, plus ``retry_after`` (seconds)
    when the server's write queue was full (the window was not stored)."""
    if isinstance(exc, TactusError):
        problem = problem_for_exception(exc)
    else:
        log.error("storing a touch window failed on stream %s", stream_id, exc_info=exc)
        problem = problem_body(500, f"storing failed ({type(exc).__name__}); see the server log")
    message: dict[str, Any] = {"type": "error", "error": problem, "windows": [seq]}
    if isinstance(exc, OverloadedError):
        message["retry_after"] = exc.retry_after
    return message


async def _try_send(send: Any, message: dict[str, Any]) -> None:
    """Acks after the client left are dropped (the windows are stored all the same)."""
    with contextlib.suppress(Exception):
        await send(message)


def _parse(
    message: dict[str, Any], index: int, params: StreamParams, max_bytes: int
) -> tuple[np.ndarray, np.ndarray]:
    """One WebSocket message -> (frames (M, 32, 32), times (M,) float64): a binary ``.npy``
    of M frames is parsed and timed as one array."""
    data = message.get("bytes")
    if data is not None:
        if len(data) > max_bytes:
            raise InvalidInputError(f"message is {len(data)} bytes; the limit is {max_bytes}")
        arr = load_npy(data, f"binary frame {index}", frames=True)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1:] != FRAME_SHAPE:
            raise InvalidInputError(
                f"binary frame {index} has shape {arr.shape}, expected (32, 32) or (N, 32, 32)"
            )
        m = arr.shape[0]
        if params.hz is not None:
            times = params.t0 + (index + np.arange(m, dtype=np.float64)) / params.hz
        else:
            times = np.full(m, time.time())
        return arr, times
    text = message.get("text")
    if text is None:
        raise InvalidInputError(f"message {index} is empty")
    if len(text) > max_bytes:
        raise InvalidInputError(f"message is {len(text)} characters; the limit is {max_bytes}")
    obj = loads_strict(text)
    if not isinstance(obj, dict) or "frame" not in obj:
        raise InvalidInputError(
            f'message {index} must be a JSON object {{"frame": [[...32] x 32], "t": ...}}'
        )
    frame = as_frame(obj["frame"], f"frame {index}")
    return frame[None], np.array([_frame_time(obj, index)])
