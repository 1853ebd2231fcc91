"""Messages into items: how the messages of a recording's mapped topics become the items of
their senses (decoded by the sense, windowed by a windowed sense, idle windows counted), with
ids that depend only on the recording and the message, so ingesting a file twice adds
nothing. Picklable (:class:`DecodeSpec`): the Ray path decodes on workers with the same spec.
"""

from __future__ import annotations

import hashlib
import re
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import tactus_memory.adapters.decode as decode
from tactus_memory.errors import IdleWindowError, TactusError
from tactus_memory.recordings.reader import Recording
from tactus_memory.senses.windowed import WindowedSense
from tactus_memory.storage.rows import options_for

NS = 1_000_000_000


def item_id(*parts: object) -> str:
    return hashlib.sha256("\x1f".join(str(p) for p in parts).encode()).hexdigest()[:32]


@dataclass
class TopicPlan:
    """A mapped topic: its sense, and how its messages become items."""

    topic: str
    sense: str
    source: str
    skip_reason: str | None = None  # every message skipped for this reason


@dataclass
class Tally:
    """Messages read on the mapped topics; why items were not stored (reason -> count)."""

    messages: int = 0
    skipped: Counter[str] = field(default_factory=Counter)


@dataclass(frozen=True)
class Decoded:
    """One item of a recording, validated by its sense, with the id every ingest gives it."""

    topic: str
    id: str
    item: Any
    t: float
    t_end: float
    meta: dict[str, Any]


def accept(sense: Any, item: Any, keep_idle: bool, tally: Tally) -> Any | None:
    """The sense's own checks; a refused item is counted in ``tally`` with the reason (an
    idle touch window, refused by the touch sense's idle rule, unless ``keep_idle``)."""
    try:
        return sense.validate(item, **options_for(sense, {"keep_idle": keep_idle}))
    except IdleWindowError:  # no contact: never embedded as a grasp (touch/windows.py)
        tally.skipped[f"{sense.name}: idle window (no contact)"] += 1
        return None
    except TactusError as exc:
        # numbers blanked so that one kind of refusal is one reason in the summary
        why = re.sub(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", "#", str(exc))
        tally.skipped[f"{sense.name}: refused, {type(exc).__name__}: {why}"[:200]] += 1
        return None


@dataclass(frozen=True)
class DecodeSpec:
    """How the messages of a recording become items (picklable: the Ray path,
    :mod:`tactus_memory.recordings.ray_jobs`, decodes on workers with the same spec, so the ids
    match)."""

    session: str
    plan: dict[str, TopicPlan]
    t0: int | None
    window: int
    stride: int
    keep_idle: bool

    def items(
        self,
        rec: Recording,
        senses: Mapping[str, Any],
        tally: Tally,
        topics: Sequence[str] | None = None,
    ) -> Iterator[Decoded]:
        """The items of ``rec`` on ``topics`` (default: all planned), in message order; a
        topic's items and ids do not depend on the other topics read with it."""
        digest = rec.digest
        name = rec.path.name
        index: Counter[str] = Counter()
        streams: dict[str, Any] = {}  # topic -> the sense's window_stream
        for m in rec.messages(sorted(self.plan if topics is None else topics)):
            topic = self.plan[m.topic]
            tally.messages += 1
            i = index[m.topic]
            index[m.topic] += 1
            if topic.skip_reason is not None:
                tally.skipped[topic.skip_reason] += 1
                continue
            ns = decode.stamp_ns(m.msg) or m.log_time_ns
            t = ns / NS if self.t0 is None else (ns - self.t0) / NS
            where = f"{name} topic {m.topic!r} message {i}"
            meta = {"topic": m.topic, "type": m.msgtype, "recording": name}
            sense = senses[topic.sense]
            raw = sense.from_message(m.msg, m.msgtype, where)  # the sense decodes its own
            if not isinstance(sense, WindowedSense):
                item = accept(sense, raw, self.keep_idle, tally)
                if item is not None:
                    iid = item_id(self.session, digest, m.topic, ns, i)
                    yield Decoded(m.topic, iid, item, t, t, meta)
                continue
            if m.topic not in streams:  # the sense cuts its own windows
                streams[m.topic] = sense.window_stream(self.window, self.stride)
            done = streams[m.topic].push(raw, [t])  # raw: one (H, W) frame
            for w in range(len(done)):
                window = done.frames[w]  # (K, H, W)
                item = accept(sense, window, self.keep_idle, tally)
                if item is None:
                    continue
                wid = item_id(self.session, digest, m.topic, self.window, self.stride,
                               int(done.start[w]), repr(float(done.t[w])))  # fmt: skip
                wmeta = {**meta, "frames": int(window.shape[0]), "first_frame": int(done.start[w])}
                yield Decoded(m.topic, wid, item, float(done.t[w]), float(done.t_end[w]), wmeta)
        for topic_name, ws in streams.items():
            if ws.pending:
                sense_name = self.plan[topic_name].sense
                tally.skipped[f"{sense_name}: frames after the last full window"] += ws.pending
