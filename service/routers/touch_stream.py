"""Live touch: WebSocket ``/sessions/{session}/touch/stream``, frames in, stored windows out;
``/sessions/{session}/senses/{sense}/stream`` the same for any windowed sense (an IMU's frames
are (C,) instead of (H, W)): the sense's frame shape, its stream cutter
(``WindowedSense.window_stream``) and its ``validate`` (the idle rule) do the sense's part.

Protocol (all server messages are JSON objects with a ``type``):

* connect with optional query parameters ``sense`` (the touch sense to write to, default
  ``touch``, the 32x32 glove: each touch sense reads frames of its own shape H x W),
  ``window`` (K, frames per window), ``stride``
  (frames between window starts; ``stride > window`` skips frames), ``calibrated``
  (frames already calibrated; default false = raw sensor units), ``hz`` and ``t0`` (times
  for binary frames: frame i gets ``t0 + i / hz``; without ``hz`` the server clock), and
  ``token`` (or an ``Authorization: Bearer`` header) when the server has a token.
* the server answers ``{"type": "ready", "window": K, "stride": S, ...}`` (with
  ``--workers N``, also ``"worker": i``, the process that holds the connection).
* send frames one by one: text ``{"frame": [[...W] x H], "t": 12.5}``, or binary ``.npy``
  bytes of an (H, W) frame, or of (N, H, W) frames (parsed, timed and windowed as one
  array); H x W is the sense's frame shape, and a frame of another shape is an error naming
  both shapes.
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

Each message is parsed, windowed and its windows validated on a write thread (off the event
loop, one call per message) and handed to the service's group committer
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
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, WebSocket, WebSocketDisconnect

from tactus_memory.errors import IdleWindowError, InvalidInputError, OverloadedError, TactusError
from tactus_memory.limits import MAX_WINDOW_FRAMES
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.senses.windowed import WindowCutter
from tactus_memory.service.arrays import as_window_array, load_npy, loads_strict, shape_name
from tactus_memory.service.deps import (
    PrincipalDep,
    SessionId,
    SettingsDep,
    StateDep,
    TenantDep,
    Writable,
    Write,
)
from tactus_memory.service.problems import problem_body, problem_for_exception
from tactus_memory.service.touch_senses import TouchSenseDep, WindowedSenseDep, frame_shape
from tactus_memory.times import check_time

log = logging.getLogger("tactus_memory.service")

router = APIRouter(tags=["touch"])
#: the same stream for any windowed sense, by the name in the path
windows_router = APIRouter(tags=["windows"])

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
        self.t0 = check_time(self._float(query.get("t0", "0"), "t0"), "t0")

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
    return check_time(obj["t"], f"frame message {index}: 't'")


def stream_params(websocket: WebSocket, settings: SettingsDep) -> StreamParams:
    """The connection's query parameters (a bad one refuses the socket: 422, 1008)."""
    return StreamParams(websocket.query_params, settings.window, settings.stride)


@router.websocket(
    "/sessions/{session}/touch/stream", name="touch_stream", dependencies=[Write, Writable]
)
async def touch_stream(
    websocket: WebSocket,
    session: SessionId,
    state: StateDep,
    tenant: TenantDep,
    principal: PrincipalDep,
    params: Annotated[StreamParams, Depends(stream_params)],
    sense: TouchSenseDep,
) -> None:
    """The token, the session id, a writable store and the touch sense (``?sense=``) are
    checked by the same dependencies as the HTTP routes (the app includes this router with
    the token)."""
    route = "WS /sessions/{session}/touch/stream"
    await _serve(websocket, session, state, tenant, principal, params, sense, route)


@windows_router.websocket(
    "/sessions/{session}/senses/{sense}/stream",
    name="windows_stream",
    dependencies=[Write, Writable],
)
async def windows_stream(
    websocket: WebSocket,
    session: SessionId,
    state: StateDep,
    tenant: TenantDep,
    principal: PrincipalDep,
    params: Annotated[StreamParams, Depends(stream_params)],
    sense: WindowedSenseDep,
) -> None:
    """The touch stream's protocol for the windowed sense the path names."""
    route = "WS /sessions/{session}/senses/{sense}/stream"
    await _serve(websocket, session, state, tenant, principal, params, sense, route)


async def _serve(
    websocket: WebSocket,
    session: str,
    state: Any,
    tenant: Any,
    principal: Any,
    params: StreamParams,
    sense: Any,
    route: str,
) -> None:
    """One stream of frames of the windowed ``sense`` (either route), until the client
    leaves; ``route`` names it in the audit log."""
    target = _Target(sense.name, frame_shape(sense))
    send_lock = asyncio.Lock()

    async def send(message: dict[str, Any]) -> None:
        async with send_lock:
            await websocket.send_text(json.dumps(message))

    await websocket.accept()

    stream_id = "ws-" + uuid.uuid4().hex[:16]
    # the sense's own stream cutter (the windowed-sense contract), raw windows: the sense
    # calibrates each window once (its own profile) and refuses an idle one (IdleWindowError)
    windower = sense.window_stream(params.window, params.stride)
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
            "sense": target.sense,
            "shape": list(target.shape),
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
            # a JSON frame or a binary message of several frames is parsed and windowed on the
            # write threads; the sense's checks of the windows it completes always are
            assert state.write_threads is not None
            job = (
                message, frame_index, params, state.settings.max_ws_message_bytes, windower,
                tenant.open_committer(), session, stream_id, target,
            )  # fmt: skip
            try:
                if _inline(message):
                    done = _ingest(*job, queue=False)
                    if done.completed is not None and len(done.completed):
                        done = await state.write_threads.run(
                            _queue_windows, done, params.calibrated, *job[5:]
                        )
                else:
                    done = await state.write_threads.run(_ingest, *job)
            except TactusError as exc:
                await send(
                    {"type": "error", "error": problem_for_exception(exc), "frame": frame_index}
                )
                frame_index += 1
                continue
            frame_index += done.frames
            for t_first, t_last, outcome in done.windows:
                if isinstance(outcome, IdleWindowError):  # no contact: never stored as a grasp
                    await send({"type": "idle", "seq": seq, "t": t_first, "t_end": t_last})
                elif isinstance(outcome, BaseException):  # invalid, or the write queue is full
                    await send(_window_error(outcome, seq, stream_id))
                else:
                    await acks.put((seq, t_first, t_last, asyncio.wrap_future(outcome)))
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


#: a binary message this small (``np.save`` of one (32, 32) float64 frame: 8,320 bytes) is
#: parsed and windowed on the event loop: that takes ~40-50 us, a hop to a write thread and
#: back ~150-200 us (measured on the 2-core machine, docs/operations/speed.md); a JSON frame
#: (~1.4 ms to parse) or a larger binary message is parsed on the write threads
INLINE_BINARY_BYTES = 8_320


def _inline(message: Mapping[str, Any]) -> bool:
    data = message.get("bytes")
    return data is not None and len(data) <= INLINE_BINARY_BYTES


@dataclass
class _Ingested:
    """What one message gave: its frame count, the windows it completed (until queued), and
    per queued window its (t, t_end) and outcome: the queued write's future, or the error that
    refused it (idle included)."""

    frames: int
    completed: Any = None  # the cutter's completed windows (``.frames``, ``.t``...)
    windows: list[tuple[float, float, Future[list[str]] | TactusError]] = field(
        default_factory=list
    )


@dataclass(frozen=True)
class _Target:
    """The windowed sense a stream writes to and its frame shape ((H, W) for touch)."""

    sense: str
    shape: tuple[int, ...]


def _ingest(
    message: Mapping[str, Any],
    index: int,
    params: StreamParams,
    max_bytes: int,
    windower: WindowCutter,
    committer: GroupCommitter,
    session: str,
    stream_id: str,
    target: _Target,
    *,
    queue: bool = True,
) -> _Ingested:
    """One WebSocket message: parsed (M frames, one array) and windowed (one push); ``queue``:
    and its completed windows queued too (:func:`_queue_windows`). A bad message raises."""
    frames, times = _parse(message, index, params, max_bytes, target)
    done = _Ingested(len(frames), windower.push(frames, times))
    if not queue:
        return done
    return _queue_windows(done, params.calibrated, committer, session, stream_id, target)


def _queue_windows(
    done: _Ingested,
    calibrated: bool,
    committer: GroupCommitter,
    session: str,
    stream_id: str,
    target: _Target,
) -> _Ingested:
    """On a write thread: each completed window validated by the touch sense and queued for
    the group commit (``GroupCommitter.submit``, the one library write call)."""
    wins = done.completed
    assert wins is not None
    for win, t_first, t_last in zip(wins.frames, wins.t, wins.t_end, strict=True):
        span = (float(t_first), float(t_last))
        try:
            queued = committer.submit(
                session,
                target.sense,
                win[None],  # (1, K, H, W)
                t=[span[0]],
                t_end=[span[1]],
                source=stream_id,
                options={"calibrated": calibrated},
                skip_idle=False,  # one window: an "idle" message instead
            )
        except TactusError as exc:
            done.windows.append((*span, exc))
        else:
            done.windows.append((*span, queued))
    done.completed = None
    return done


def _parse(
    message: Mapping[str, Any], index: int, params: StreamParams, max_bytes: int, target: _Target
) -> tuple[np.ndarray, np.ndarray]:
    """One WebSocket message -> (frames (M, *F), times (M,) float64), F the frame shape of the
    stream's windowed sense ((H, W) for touch): a binary ``.npy`` of M frames is parsed and
    timed as one array."""
    shape, sense = target.shape, target.sense
    dims = ", ".join(map(str, shape))
    data = message.get("bytes")
    if data is not None:
        if len(data) > max_bytes:
            raise InvalidInputError(f"message is {len(data)} bytes; the limit is {max_bytes}")
        arr = load_npy(data, f"binary frame {index}", frames=True)
        sent = arr.shape
        if arr.ndim == len(shape):
            arr = arr[None]
        if arr.ndim != len(shape) + 1 or arr.shape[1:] != shape:
            raise InvalidInputError(
                f"binary frame {index} has shape {sent}, expected ({dims}) or "
                f"(N, {dims}): sense {sense!r} reads {shape_name(shape)} frames"
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
            f'message {index} must be a JSON object {{"frame": {_frame_words(shape)}, "t": ...}}'
        )
    frame = as_window_array(obj["frame"], "", f"frame {index}", shape, sense)
    return frame[None], np.array([_frame_time(obj, index)])


def _frame_words(shape: tuple[int, ...]) -> str:
    """How an error draws one frame of ``shape``: ``[[...32] x 32]`` for (32, 32)."""
    words = f"[...{shape[-1]}]"
    for n in reversed(shape[:-1]):
        words = f"[{words} x {n}]"
    return words
