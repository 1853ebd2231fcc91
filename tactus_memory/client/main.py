"""``Client``: the memory's Python API over the service's HTTP, from another machine.

```python
from tactus_memory import Client

with Client("http://robot-1:8000", token="s3cret") as memory:      # like Memory.open(...)
    memory.add("kitchen", "text", "the mug was hot", t=3.0)
    hits = memory.search("holding a mug", k=5, session="kitchen")  # list[Hit]
    when = memory.last("put the mug down", session="kitchen")      # Moment | None
    with memory.stream_touch("kitchen", hz=30) as glove:           # the WebSocket
        for frame in frames:                                       # (32, 32) raw
            glove.send(frame)
```

Same method names, arguments and result types as :class:`~tactus_memory.memory.main.Memory` for
what the service offers (tests/client/test_client_parity.py runs one scenario against both). One
``httpx.Client`` keeps the connections open; a 503 or 429 with ``Retry-After`` is retried
after that many seconds (at most ``retries`` times, each wait at most ``max_retry_wait``);
a problem answer raises the library's own exception named by its type
(:func:`~tactus_memory.client.errors.problem_error`).

Differences, because HTTP offers no more: text ``add_many`` is one request per note (not one
commit); writes take no ``source`` (a touch stream sets its own); touch frames are raw sensor
units unless ``options={"calibrated": True}``; an unset ``t`` is this machine's clock.
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from email.utils import parsedate_to_datetime
from typing import Any

import httpx
import numpy as np
from typing_extensions import Unpack

from tactus_memory.batches import (
    AddKwargs,
    WriteKwargs,
    check_ids,
    check_times,
    meta_json,
    one_item,
    per_item,
)
from tactus_memory.client.errors import problem_error
from tactus_memory.client.params import match_params, npy, scope_params
from tactus_memory.client.stream import TouchStream
from tactus_memory.client.teach import TeachingCalls
from tactus_memory.contract import MemoryAPI
from tactus_memory.errors import InvalidInputError, NotFoundError, TactusError
from tactus_memory.identity import auth_headers, validate_tenant
from tactus_memory.matching import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    AroundKwargs,
    MatchKwargs,
    OccurrenceKwargs,
    grasp_params,
    split_match,
)
from tactus_memory.query import Scope, ScopeKwargs, TimelineKwargs, timeline_scope
from tactus_memory.results import (
    ClockOffset,
    Context,
    Episode,
    Grasp,
    Hit,
    Moment,
    Occurrences,
    SenseInfo,
    SessionSummary,
    Timeline,
    TimelineItem,
)
from tactus_memory.senses.base import Sense
from tactus_memory.where import check_sort

#: retry answers: overload (503, the write queue) and rate limits (429)
RETRY_STATUSES = (429, 503)


def retry_after(response: httpx.Response) -> float | None:
    """Seconds from a ``Retry-After`` header (delta-seconds or an HTTP date), else None."""
    value = response.headers.get("retry-after")
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        try:
            return max(0.0, parsedate_to_datetime(value).timestamp() - time.time())
        except (TypeError, ValueError):
            return None


def error_from(response: httpx.Response) -> TactusError:
    """A problem answer -> the library's exception for its type (see ``problem_error``)."""
    try:
        problem = response.json()
    except ValueError:
        problem = {"detail": response.text[:500]}
    if not isinstance(problem, dict):
        problem = {"detail": str(problem)[:500]}
    return problem_error(response.status_code, problem, retry_after(response))


def image_bytes(image: Any) -> bytes:
    """An image item as encoded bytes: bytes as they are, a PIL image as PNG."""
    if isinstance(image, (bytes, bytearray)):
        return bytes(image)
    if hasattr(image, "save"):
        buf = io.BytesIO()
        image.save(buf, format="PNG")
        return buf.getvalue()
    raise InvalidInputError(f"an image is PNG/JPEG bytes or a PIL image, not {type(image)}")


class Client(TeachingCalls, AbstractContextManager["Client"]):
    """The service at ``url`` with the :class:`~tactus_memory.memory.main.Memory` API."""

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        tenant: str | None = None,
        timeout: float = 60.0,
        retries: int = 3,
        max_retry_wait: float = 30.0,
        transport: httpx.BaseTransport | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.url = url.rstrip("/")
        self.token = token
        #: the tenant the operator's token acts for (``X-Tactus-Tenant``; a key's is its own)
        self.tenant = None if tenant is None else validate_tenant(tenant)
        self.retries = int(retries)
        self.max_retry_wait = float(max_retry_wait)
        self._sleep = sleep
        #: what every call and the touch stream send: the token, the operator's tenant
        self.headers = auth_headers(token, self.tenant)
        self.http = httpx.Client(
            base_url=self.url,
            headers=self.headers,
            timeout=timeout,
            transport=transport or httpx.HTTPTransport(retries=1),  # connect errors only
        )

    # ----------------------------------------------------------------- plumbing
    def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        """One call, retried on 503/429 with Retry-After; a problem answer raises."""
        for attempt in range(self.retries + 1):
            r = self.http.request(method, path, **kw)
            if r.status_code not in RETRY_STATUSES or attempt == self.retries:
                break
            wait = retry_after(r)
            if wait is None and r.status_code == 429:
                wait = 0.5 * 2**attempt
            if wait is None or wait > self.max_retry_wait:
                break
            self._sleep(wait)
        if r.status_code >= 400:
            raise error_from(r)
        return r

    def _get(self, path: str, params: Mapping[str, Any] | None = None) -> Any:
        return self.request("GET", path, params=params).json()

    def close(self) -> None:
        self.http.close()

    def __exit__(self, *exc: object) -> None:  # ``with``: __enter__ (self) from the base
        self.close()

    def __repr__(self) -> str:
        return f"Client({self.url!r})"

    # ----------------------------------------------------------------- writes
    def add(self, session: str, sense: str, item: Any, **kw: Unpack[AddKwargs]) -> str:
        """Remember one item; returns its id (see :meth:`Memory.add`)."""
        return self.add_many(session, sense, [item], **one_item(kw))[0]

    def add_many(
        self, session: str, sense: str, items: Sequence[Any], **kw: Unpack[WriteKwargs]
    ) -> list[str]:
        """Remember N items of one sense; returns their ids (see :meth:`Memory.add_many`).
        Touch and vector batches are one request (one commit); text is one request each."""
        if kw.get("source"):
            raise InvalidInputError(
                "source is not offered by the service's write routes (a touch stream sets its own)"
            )
        items = list(items)
        n = len(items)
        # the checks the memory's write path makes, before anything is sent
        times, ends, _ = check_times(n, kw.get("t"), kw.get("t_end"))
        metas = per_item(kw.get("meta"), n, "meta")
        for m in metas:
            meta_json(m)
        ids = None if kw.get("ids") is None else check_ids(n, kw.get("ids"))
        # batch bodies take a meta per item or none at all (an absent meta is stored as {})
        batch_meta = None if all(m is None for m in metas) else [m or {} for m in metas]
        base = f"/sessions/{session}"
        if sense == "text":
            out = []
            for i, text in enumerate(items):
                body = {"text": text, "t": times[i], "t_end": ends[i], "meta": metas[i]}
                if ids is not None:
                    body["id"] = ids[i]
                out += self.request("POST", base + "/text", json=body).json()["ids"]
            return out
        if sense == "image":  # multipart, one request per image: encoded bytes or a PIL image
            out = []
            for i, image in enumerate(items):
                form = {"t": str(times[i]), "t_end": str(ends[i])}
                if metas[i] is not None:
                    form["meta"] = json.dumps(metas[i])
                if ids is not None:
                    form["id"] = ids[i]
                files = {"file": ("image", image_bytes(image))}
                r = self.request("POST", base + "/image", data=form, files=files)
                out += r.json()["ids"]
            return out
        # a touch sense (the glove, or another sensor's: GET /senses modality) -> ?sense=
        if sense == "touch" or any(i.name == sense and i.modality == "touch"
                                   for i in self.sense_info()):  # fmt: skip
            calibrated = bool((kw.get("options") or {}).get("calibrated", False))
            base = base + "/touch"
            params: dict[str, Any] = {"sense": sense}
            if ids is None and all(m is None for m in metas):  # binary: any batch, exact
                params |= {"t": times, "t_end": ends, "calibrated": calibrated}
                arr = np.stack([np.asarray(w) for w in items]) if items else np.zeros((0,))
                r = self.request(
                    "POST",
                    base,
                    content=npy(arr),
                    params=params,
                    headers={"Content-Type": "application/x-npy"},
                )
                return r.json()["ids"]
            body = {
                "windows": [np.asarray(w).tolist() for w in items],
                "t": times,
                "t_end": ends,
                "meta": batch_meta,
                "ids": ids,
                "calibrated": calibrated,
            }
            return self.request("POST", base, json=body, params=params).json()["ids"]
        body = {
            "sense": sense,
            "vectors": [np.asarray(v, dtype=float).tolist() for v in items],
            "t": times,
            "t_end": ends,
            "meta": batch_meta,
            "ids": ids,
        }
        return self.request("POST", base + "/vectors", json=body).json()["ids"]

    def add_sense(self, sense: Sense) -> None:
        """Register a :class:`~tactus_memory.adapters.vectors.VectorSense` (precomputed vectors):
        the one kind of sense the service registers over HTTP (``POST /senses``)."""
        if getattr(sense, "modality", None) != "vector":
            raise InvalidInputError(
                f"over HTTP only a VectorSense can be registered, not {type(sense).__name__}"
            )
        body = {"name": sense.name, "dim": sense.dim, "space": sense.space_name}
        body.update(sense.provenance())
        self.request("POST", "/senses", json={k: v for k, v in body.items() if v is not None})

    def delete_session(self, session: str) -> int:
        """Delete every item of a session; returns the rows removed (0 for a session that
        does not exist, as :meth:`Memory.delete_session`; the service answers that 404)."""
        try:
            return int(self.request("DELETE", f"/sessions/{session}").json()["deleted"])
        except NotFoundError:
            return 0

    def stream_touch(self, session: str, **params: Any) -> TouchStream:
        """A live glove: ``with client.stream_touch("s1", hz=30) as s: s.send(frame)``
        (see :class:`~tactus_memory.client.stream.TouchStream` for ``params``)."""
        ws = "ws" + self.url[4:] if self.url.startswith("http") else self.url
        url = f"{ws}/sessions/{session}/touch/stream"
        return TouchStream(url, self.headers, **params)

    # ----------------------------------------------------------------- search
    def search(
        self,
        query: str,
        k: int = 10,
        *,
        group: str | None = "auto",
        gap: float | None = None,
        pool: str = "mean",
        sort: str | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit] | list[Moment] | list[Grasp]:
        """Natural-language search (see :meth:`Memory.search`): touch answers are grasps by
        default (``group="auto"``), ``group="window"`` one hit per stored window; ``sort``
        orders by a touch facet or time."""
        params = {"q": query, "k": k, "pool": pool, **scope_params(Scope.of(**scope))}
        if check_sort(sort) is not None:
            params["sort"] = sort
        if group is not None:
            params["group"] = group
        if gap is not None:
            params["gap"] = gap
        body = self._get("/search", params)
        if group == "grasp":
            return [Grasp.model_validate(g) for g in body["grasps"] or []]
        if group == "moment":
            return [Moment.model_validate(m) for m in body["moments"] or []]
        return [Hit.model_validate(h) for h in body["hits"]]

    def search_moments(
        self,
        query: str,
        k: int = 10,
        *,
        gap: float = DEFAULT_MOMENT_GAP,
        sort: str | None = None,
        **kw: Unpack[MatchKwargs],
    ) -> list[Moment]:
        """Search grouped into moments (see :meth:`Memory.search_moments`)."""
        rest: dict[str, Any] = {**kw, "sort": sort}
        params = {"q": query, "k": k, "gap": gap, **grasp_params(rest)}
        scope, match = split_match(rest)
        params.update(scope_params(scope), **match_params(match))
        return [Moment.model_validate(m) for m in self._get("/moments", params)["moments"]]

    def search_like(
        self,
        sense: str,
        example: Any = None,
        k: int = 10,
        *,
        vector: Sequence[float] | np.ndarray | None = None,
        options: Mapping[str, Any] | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit]:
        """Query by example (see :meth:`Memory.search_like`)."""
        where = scope_params(Scope.of(**scope))
        body: dict[str, Any] = {"sense": sense, "k": k, "senses": where.pop("sense", None)}
        body.update(where)
        if vector is not None:
            body["vector"] = np.asarray(vector, dtype=float).tolist()
        elif isinstance(example, str):
            body["text"] = example
        elif example is not None:
            body["frames"] = np.asarray(example).tolist()
            body["calibrated"] = bool((options or {}).get("calibrated", False))
        else:
            raise InvalidInputError("search_like needs an example or vector=")
        body = {k: v for k, v in body.items() if v is not None}
        hits = self.request("POST", "/search/like", json=body).json()["hits"]
        return [Hit.model_validate(h) for h in hits]

    # ----------------------------------------------------------------- temporal questions
    def occurrences(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Occurrences:
        """Distinct occurrences of ``query`` (see :meth:`Memory.occurrences`): the keywords
        ``merge_gap``, ``per_stream``, ``group``, ``pool``, ``sort`` and the scope's and
        match's."""
        rest: dict[str, Any] = dict(kw)
        merge_gap = rest.pop("merge_gap", DEFAULT_MERGE_GAP)
        per_stream = rest.pop("per_stream", False)
        extra = grasp_params(rest)
        scope, match = split_match(rest)
        params = {"q": query, "merge_gap": merge_gap, "per_stream": per_stream, **extra}
        params.update(scope_params(scope), **match_params(match))
        return Occurrences.model_validate(self._get("/count", params))

    def count(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> int:
        """How many distinct times ``query`` happened."""
        return self.occurrences(query, **kw).count

    def _one(self, path: str, query: str, kw: OccurrenceKwargs) -> Moment | None:
        rest: dict[str, Any] = dict(kw)
        merge_gap = rest.pop("merge_gap", DEFAULT_MERGE_GAP)
        extra = grasp_params(rest)
        scope, match = split_match(rest)
        params = {"q": query, "merge_gap": merge_gap, **scope_params(scope), **extra}
        params.update(match_params(match))
        moment = self._get(path, params)["moment"]
        return None if moment is None else Moment.model_validate(moment)

    def last(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The most recent occurrence of ``query``, or None."""
        return self._one("/last", query, kw)

    def first(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The earliest occurrence of ``query``, or None."""
        return self._one("/first", query, kw)

    def _around(self, side: str, anchor: str, window: float, kw: AroundKwargs) -> Context | None:
        rest: dict[str, Any] = dict(kw)
        anchor_senses = rest.pop("anchor_senses", None)
        scope, match = split_match(rest)
        params = {"anchor": anchor, "window": window, **scope_params(scope)}
        params.update(match_params(match))
        if anchor_senses is not None:
            params["anchor_sense"] = list(anchor_senses)
        body = self._get(f"/{side}", params)
        return None if body.get("anchor") is None else Context.model_validate(body)

    def before(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``."""
        return self._around("before", anchor, window, kw)

    def after(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor``."""
        return self._around("after", anchor, window, kw)

    def timeline(self, session: str, **kw: Unpack[TimelineKwargs]) -> Timeline:
        """The session's items or episodes in aligned time order (:meth:`Memory.timeline`)."""
        scope, limit = timeline_scope(None, kw)
        episodes = bool(kw.get("episodes", False))
        params: dict[str, Any] = {**scope_params(scope), "episodes": episodes}
        if limit is not None:
            params["limit"] = limit
        body = self._get(f"/sessions/{session}/timeline", params)
        if episodes:
            return [Episode.model_validate(e) for e in body["episodes"]]
        return [TimelineItem.model_validate(i) for i in body["items"]]

    def episodes(
        self, session: str, *, senses: Sequence[str] | None = None, source: str | None = None
    ) -> list[Episode]:
        """The session's episodes in aligned time order."""
        return self.timeline(session, senses=senses, episodes=True, source=source)  # type: ignore[return-value]

    def segment_episodes(self, session: str, **rule: float) -> int:
        """Segment a session's streams into stored episodes; returns how many."""
        r = self.request("POST", f"/sessions/{session}/episodes", json=rule)
        return int(r.json()["episodes"])

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock."""
        body = {"sense": sense, "offset": offset, "source": source}
        self.request("PUT", f"/sessions/{session}/clock", json=body)

    def clock_offsets(self, session: str) -> list[ClockOffset]:
        """The session's clock offsets (over HTTP a session must be named)."""
        body = self._get(f"/sessions/{session}/clock")
        return [ClockOffset.model_validate(o) for o in body["offsets"]]

    # ----------------------------------------------------------------- sessions, senses
    def sessions(self) -> list[SessionSummary]:
        """A summary per session (counts per sense, time span), sorted by id."""
        body = self._get("/sessions")
        return [SessionSummary.model_validate(s) for s in body["sessions"]]

    def session(self, session: str) -> SessionSummary:
        return SessionSummary.model_validate(self._get(f"/sessions/{session}"))

    def session_ids(self) -> list[str]:
        return [s.id for s in self.sessions()]

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows, with row counts and calibration."""
        return [SenseInfo.model_validate(s) for s in self._get("/senses")["senses"]]


#: checked by the type checker (``make lint``): Client implements the memory's contract
_CONTRACT: type[MemoryAPI] = Client
