"""A live glove over the service's WebSocket (``/sessions/{id}/touch/stream``), for
:meth:`tactus_memory.client.main.Client.stream_touch`.

```python
with client.stream_touch("kitchen", hz=30) as glove:   # window/stride: the server's default
    for frame in frames:                                # (32, 32) raw sensor units
        glove.send(frame)                               # or glove.send(frame, t=12.5)
print(glove.ids, glove.idle, glove.errors)              # after every window was answered
```

A reader thread collects the server's answers: ``stored`` windows (their ids, in order),
``idle`` windows (no contact, not stored) and ``errors`` (problem details, with the frame or
window they concern). Leaving the block waits (at most ``timeout`` seconds) until every full
window sent has been answered, so the ids are those of committed windows.
"""

from __future__ import annotations

import contextlib
import io
import json
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from tactus_memory.client.errors import problem_error
from tactus_memory.errors import InvalidInputError


class TouchStream:
    """One WebSocket touch stream; use as a context manager."""

    def __init__(
        self,
        url: str,
        headers: Mapping[str, str] | None = None,
        *,
        window: int | None = None,
        stride: int | None = None,
        calibrated: bool = False,
        hz: float | None = None,
        t0: float | None = None,
        timeout: float = 60.0,
        sense: str | None = None,
    ) -> None:
        query = {"sense": sense, "window": window, "stride": stride, "hz": hz, "t0": t0}
        parts = [f"{k}={v}" for k, v in query.items() if v is not None]
        parts.append(f"calibrated={'true' if calibrated else 'false'}")
        self.url = url + "?" + "&".join(parts)
        #: the connection's headers (the client's: its token, the operator's tenant)
        self.headers = dict(headers or {})
        self.timeout = float(timeout)
        self.ids: list[str] = []
        self.idle: list[dict[str, Any]] = []
        self.errors: list[dict[str, Any]] = []
        self.window = 0
        self.stride = 1
        self.frames_sent = 0
        self.shape: tuple[int, ...] | None = None  # (H, W): the server's ready message says
        self._answered = 0  # windows answered (stored, idle, or refused)
        self._bad_frames = 0
        self._changed = threading.Condition()
        self._ws: ClientConnection | None = None
        self._reader: threading.Thread | None = None

    def __enter__(self) -> TouchStream:
        self._stack = contextlib.ExitStack()
        opened = connect(self.url, additional_headers=self.headers, open_timeout=self.timeout)
        self._ws = self._stack.enter_context(opened)
        first = json.loads(self._ws.recv(timeout=self.timeout))
        if first.get("type") != "ready":
            self._stack.close()
            problem = first.get("error", {})
            raise problem_error(int(problem.get("status", 500)), problem)
        self.window, self.stride = int(first["window"]), int(first["stride"])
        self.stream_id = first.get("stream")
        #: (H, W) of one frame of the stream's touch sense (the server's ready message)
        self.shape = tuple(first["shape"])
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        return self

    def _read(self) -> None:
        assert self._ws is not None
        try:
            for raw in self._ws:
                msg = json.loads(raw)
                with self._changed:
                    kind = msg.get("type")
                    if kind == "stored":
                        self.ids.append(msg["id"])
                        self._answered += 1
                    elif kind == "idle":
                        self.idle.append(msg)
                        self._answered += 1
                    elif kind == "error":
                        self.errors.append(msg)
                        self._answered += len(msg.get("windows", []))
                        self._bad_frames += int("frame" in msg)  # skipped, in no window
                    self._changed.notify_all()
        except ConnectionClosed:
            pass
        finally:
            with self._changed:
                self._changed.notify_all()

    def send(self, frame: np.ndarray, t: float | None = None) -> None:
        """One (H, W) frame, or (N, H, W) frames at once (binary, timed by ``hz``/``t0`` or
        the server's clock), H x W the stream's touch sense's frame shape (``sense=`` when
        opened; the glove's 32x32 by default); with ``t`` a single frame goes as JSON with
        that time."""
        if self._ws is None:
            raise InvalidInputError("send() outside the `with client.stream_touch(...)` block")
        arr = np.asarray(frame)
        if t is not None:
            if arr.shape != self.shape:
                raise InvalidInputError(f"a frame with t= must be {self.shape}, got {arr.shape}")
            self._ws.send(json.dumps({"frame": arr.tolist(), "t": float(t)}))
            self.frames_sent += 1
            return
        buf = io.BytesIO()
        np.save(buf, arr, allow_pickle=False)
        self._ws.send(buf.getvalue())
        self.frames_sent += 1 if arr.ndim == 2 else int(arr.shape[0])

    @property
    def windows_expected(self) -> int:
        """Full windows in the frames sent so far (what the server will answer)."""
        good = self.frames_sent - self._bad_frames
        if good < self.window:
            return 0
        return (good - self.window) // self.stride + 1

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until every full window sent has been answered; False on timeout."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        with self._changed:
            while self._answered < self.windows_expected:
                left = deadline - time.monotonic()
                if left <= 0 or self._reader is None or not self._reader.is_alive():
                    return False
                self._changed.wait(left)
        return True

    def close(self) -> None:
        if self._ws is None:
            return
        self.wait()
        self._stack.close()
        if self._reader is not None:
            self._reader.join(self.timeout)
        self._ws = None

    def __exit__(self, *exc: object) -> None:
        self.close()
