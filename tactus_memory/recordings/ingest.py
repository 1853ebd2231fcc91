"""Ingest ROS 2 bags and MCAP files into a memory: topics -> senses, messages -> items.

``ingest_recording(memory, paths, session=..., topics={"/notes": "text", "/glove": "touch"})``

* **Times**: a message's header stamp when set, else its log time; on the session clock
  (seconds from the earliest first message of the mapped topics, over all the files of the
  call) unless ``absolute=True`` (unix seconds). Touch frames are cut into windows by the
  library's stream windowing (:func:`tactus_memory.touch.windows.cut_windows`); a window spans
  its first to its last frame.
* **Safe to run twice**: every item's id is a digest of (session, file digest, topic,
  timestamp, index), items are committed in batches, and a batch's ids already in the memory
  are skipped before embedding. A second ingest of the same file adds nothing; an
  interrupted one picks up where its last commit ended.
* ``source`` = the topic as an id (``/glove/left`` -> ``glove.left``, ROS names have no dots);
  ``meta`` = ``{"topic", "type", "recording"}``.
* Images go to the sense mapped (``image``); when that sense is not registered because the
  space has no vision they are counted as skipped with that reason. Windows or notes a sense
  refuses (e.g. a touch window with no reading above the sensor offset) are skipped with the
  reason too; a mapped topic of a type the sense cannot take is a :class:`RecordingError`
  before anything is written.
"""

from __future__ import annotations

import re
import time
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, Field

import tactus_memory.adapters.decode as decode
from tactus_memory.errors import RecordingError, UnknownSenseError
from tactus_memory.names import validate_id
from tactus_memory.recordings.decoding import NS, DecodeSpec, Tally, TopicPlan
from tactus_memory.recordings.poses import (
    DEFAULT_TF,
    POSE,
    POSE_TYPES,
    TF,
    already_stored,
    check_pose_topic,
    read_poses,
    tf_ns,
)
from tactus_memory.recordings.reader import Recording, TopicInfo, open_recording
from tactus_memory.senses.plugins import lookup
from tactus_memory.where import Where

if TYPE_CHECKING:  # recordings take a memory; the memory knows nothing of them
    from tactus_memory.memory.main import Memory


#: items per commit (per sense and topic); a crash loses at most this many per topic
DEFAULT_BATCH = 256


class TopicListing(BaseModel):
    """One topic of a recording, as ``tactus ingest FILE --list`` shows it."""

    file: str
    topic: str
    type: str
    count: int
    sense: str | None = Field(description="the sense it would map to by default, or None")


class IngestSummary(BaseModel):
    """What one ingest call did."""

    session: str
    files: list[str]
    topics: dict[str, str] = Field(description="topic -> sense")
    messages: int = Field(description="messages read on the mapped topics")
    rows: dict[str, int] = Field(description="new rows per sense")
    existing: int = Field(description="items already in the memory (earlier ingest), skipped")
    skipped: dict[str, int] = Field(description="reason -> messages or windows not stored")
    poses: dict[str, int] = Field(
        default_factory=dict, description="pose topic -> poses stored (0: stored before)"
    )
    t0: float | None = Field(description="unix time of the session clock's zero (None: absolute)")
    seconds: float
    messages_per_s: float
    rows_per_s: float


def topic_source(topic: str) -> str:
    """A ROS topic name as a source id: ``/glove/left`` -> ``glove.left``."""
    s = re.sub(r"[^A-Za-z0-9._:-]", "_", topic.strip("/").replace("/", "."))
    s = s.lstrip("._:-") or "topic"
    return validate_id(s[:128], "source id")


def list_topics(paths: Sequence[str | Path] | str | Path) -> list[TopicListing]:
    """Topics, types and counts of each recording, with the sense each would map to (the
    encoding of an ``Image`` topic is read from its first message)."""
    out: list[TopicListing] = []
    for rec in [open_recording(p) for p in _paths(paths)]:
        infos = rec.topics()
        encodings: dict[str, str] = {}
        images = [i.topic for i in infos if i.msgtype == decode.IMAGE and i.count]
        if images:
            for m in rec.messages(images):
                encodings.setdefault(m.topic, str(m.msg.encoding))
                if len(encodings) == len(images):
                    break
        for i in infos:
            sense = decode.default_modality(i.msgtype, encodings.get(i.topic))
            sense = POSE if i.msgtype in POSE_TYPES else sense
            if i.encoding != "cdr":
                sense = None
            out.append(TopicListing(file=str(rec.path), topic=i.topic, type=i.msgtype or "?",
                                    count=i.count, sense=sense))  # fmt: skip
    return out


def _paths(paths: Sequence[str | Path] | str | Path) -> list[Path]:
    if isinstance(paths, (str, Path)):
        return [Path(paths)]
    return [Path(p) for p in paths]


@dataclass
class _Batch:
    ids: list[str] = field(default_factory=list)
    items: list[Any] = field(default_factory=list)
    t: list[float] = field(default_factory=list)
    t_end: list[float] = field(default_factory=list)
    meta: list[dict[str, Any]] = field(default_factory=list)


class IngestJob:
    """One ingest: the plan (checked before anything is written), the session clock, the
    poses; then the items, written here (:meth:`run`) or by Ray
    (:mod:`tactus_memory.recordings.ray_jobs`)."""

    def __init__(
        self,
        memory: Memory,
        recordings: list[Recording],
        session: str,
        topics: Mapping[str, str],
        *,
        absolute: bool,
        window: int | None,
        stride: int | None,
        batch: int,
        progress: bool,
        keep_idle: bool = False,
        tf: tuple[str, str] = DEFAULT_TF,
    ) -> None:
        self.memory = memory
        self.tf = tf
        self.pose_topics = sorted(t for t, s in topics.items() if s == POSE)
        self.poses: dict[str, int] = {}
        self.keep_idle = keep_idle
        self.recs = recordings
        self.session = validate_id(session, "session id")
        self.absolute = absolute
        self.batch_size = max(1, int(batch))
        self.progress = progress
        self.rows: Counter[str] = Counter()
        self.tally = Tally()
        self.existing = 0
        self.pending: dict[str, _Batch] = {}
        self.plan = self._plan({t: s for t, s in topics.items() if s != POSE})
        windowed = [
            s for p in self.plan.values() if (s := memory.senses.get(p.sense)) and s.windowed
        ]
        k = window or (int(getattr(windowed[0], "frames", 8)) if windowed else 8)
        self.window, self.stride = int(k), int(stride or k)

    # ------------------------------------------------------------------ planning
    def _plan(self, topics: Mapping[str, str]) -> dict[str, TopicPlan]:
        if not topics and not self.pose_topics:
            raise RecordingError("no topics to ingest: map at least one, TOPIC=SENSE")
        infos: dict[str, list[TopicInfo]] = {}
        for rec in self.recs:
            for info in rec.topics():
                infos.setdefault(info.topic, []).append(info)
        for topic in self.pose_topics:
            if topic not in infos:
                known = ", ".join(sorted(infos)) or "none"
                raise RecordingError(f"topic {topic!r} is in none of the files (topics: {known})")
            for info in infos[topic]:
                check_pose_topic(topic, info.msgtype)
        plan: dict[str, TopicPlan] = {}
        live = self.memory.senses
        for topic, sense in topics.items():
            if topic not in infos:
                known = ", ".join(sorted(infos)) or "none"
                raise RecordingError(f"topic {topic!r} is in none of the files (topics: {known})")
            found = infos[topic]
            for info in found:
                if info.encoding != "cdr":
                    raise RecordingError(
                        f"topic {topic!r} ({info.msgtype}) is encoded as {info.encoding!r}; "
                        "only ROS 2 CDR messages are read"
                    )
            if sense in live:
                supported = live[sense].message_types
                reason = None
            elif sense == "image" and not getattr(self.memory.space, "has_vision", False):
                supported = lookup("sense", "image").message_types
                reason = f"image: space {self.memory.space.name!r} has no vision, images not stored"
            else:
                raise UnknownSenseError(
                    f"topic {topic!r} maps to sense {sense!r}, which this memory does not have "
                    f"(registered: {', '.join(sorted(live))})"
                )
            for info in found:
                decode.check_supported(topic, info.msgtype, sense, supported)
            plan[topic] = TopicPlan(topic, sense, topic_source(topic), reason)
        return plan

    def _t0_ns(self) -> int | None:
        """The earliest time (ns) among the first message of each mapped topic, all files."""
        if self.absolute:
            return None
        firsts: list[int] = []
        for rec in self.recs:
            mapped = {*self.plan, *self.pose_topics}
            wanted = {i.topic for i in rec.topics() if i.topic in mapped and i.count}
            seen: set[str] = set()
            for m in rec.messages(sorted(wanted)):
                if m.topic not in seen:
                    seen.add(m.topic)
                    if m.msgtype == TF:  # a TFMessage has no header: its transforms do
                        firsts.append(tf_ns(m.msg, m.log_time_ns))
                    else:
                        firsts.append(decode.stamp_ns(m.msg) or m.log_time_ns)
                if seen >= wanted:
                    break
        return min(firsts) if firsts else 0

    # ------------------------------------------------------------------ writing
    def _queue(self, topic: TopicPlan, item_id: str, item: Any, t: float, t_end: float,
               meta: dict[str, Any]) -> None:  # fmt: skip
        b = self.pending.setdefault(topic.topic, _Batch())
        b.ids.append(item_id)
        b.items.append(item)
        b.t.append(t)
        b.t_end.append(t_end)
        b.meta.append(meta)
        if len(b.ids) >= self.batch_size:
            self._flush(topic)

    def _flush(self, topic: TopicPlan) -> None:
        b = self.pending.pop(topic.topic, None)
        if b is None or not b.ids:
            return
        where = Where().ids(b.ids).sql()
        present = set(self.memory.store.scan(where, ["id"]).column("id").to_pylist())
        keep = [i for i, x in enumerate(b.ids) if x not in present]
        self.existing += len(b.ids) - len(keep)
        if not keep:
            return
        self.memory.add_many(
            self.session,
            topic.sense,
            [b.items[i] for i in keep],
            t=[b.t[i] for i in keep],
            t_end=[b.t_end[i] for i in keep],
            meta=[b.meta[i] for i in keep],
            ids=[b.ids[i] for i in keep],
            source=topic.source,
        )
        self.rows[topic.sense] += len(keep)

    def _flush_all(self) -> None:
        for name in list(self.pending):
            self._flush(self.plan[name])

    # ------------------------------------------------------------------ reading
    def start(self) -> DecodeSpec:
        """The session clock and the poses (first: items are placed as they are written)."""
        t0 = self._t0_ns()
        self._add_poses(t0)
        return DecodeSpec(self.session, self.plan, t0, self.window, self.stride, self.keep_idle)

    def run(self) -> IngestSummary:
        from tqdm.auto import tqdm

        start = time.perf_counter()
        spec = self.start()
        total = sum(i.count for rec in self.recs for i in rec.topics() if i.topic in self.plan)
        bar = tqdm(total=total, unit="msg", unit_scale=True, disable=not self.progress,
                   desc=f"ingest {self.session}", dynamic_ncols=True)  # fmt: skip
        try:
            for rec in self.recs:
                self._one(rec, spec, bar)
        finally:
            try:
                self._flush_all()  # what was read before a failure is kept (resume)
            finally:
                bar.close()
        return self.summary(spec, time.perf_counter() - start)

    def summary(self, spec: DecodeSpec, seconds: float) -> IngestSummary:
        new, messages = sum(self.rows.values()), self.tally.messages
        return IngestSummary(
            session=self.session,
            files=[str(r.path) for r in self.recs],
            topics={p.topic: p.sense for p in self.plan.values()},
            messages=messages,
            rows=dict(self.rows),
            existing=self.existing,
            skipped=dict(self.tally.skipped),
            poses=self.poses,
            t0=None if spec.t0 is None else spec.t0 / NS,
            seconds=seconds,
            messages_per_s=messages / seconds if seconds > 0 else 0.0,
            rows_per_s=new / seconds if seconds > 0 else 0.0,
        )

    def _add_poses(self, t0: int | None) -> None:
        """The pose topics (``recordings/poses.py``) as the session's trajectory."""
        for track in read_poses(self.recs, self.pose_topics, self.tf):
            t, pos, ori = track.arrays(t0)
            if already_stored(self.memory, self.session, track.frame, t):
                self.poses[track.topic] = 0
                continue
            self.poses[track.topic] = self.memory.add_poses(
                self.session, t, pos, ori, frame=track.frame, source=topic_source(track.topic)
            )

    def _one(self, rec: Recording, spec: DecodeSpec, bar: Any) -> None:
        for d in spec.items(rec, self.memory.senses, self.tally):
            self._queue(self.plan[d.topic], d.id, d.item, d.t, d.t_end, d.meta)
            bar.update(self.tally.messages - bar.n)
        bar.update(self.tally.messages - bar.n)


def plan_ingest(
    memory: Memory,
    paths: Sequence[str | Path] | str | Path,
    *,
    session: str,
    topics: Mapping[str, str],
    absolute: bool = False,
    window: int | None = None,
    stride: int | None = None,
    batch: int = DEFAULT_BATCH,
    progress: bool = False,
    keep_idle: bool = False,
    tf: tuple[str, str] = DEFAULT_TF,
) -> IngestJob:
    """An ingest of MCAP files / ROS 2 bag folders into ``session``, checked, not yet run.

    ``topics`` maps topic -> sense name, or ``"pose"`` for the session's trajectory
    (Odometry, PoseStamped, or the ``tf`` parent -> child pair of a TFMessage topic:
    :mod:`tactus_memory.recordings.poses`). ``window`` defaults to the touch sense's K (8 for the
    shipped encoder), ``stride`` to ``window``. ``progress`` shows a tqdm bar (messages/s).
    Idle touch windows (no contact, ``touch/windows.py``) are skipped and counted in
    ``skipped`` unless ``keep_idle``.
    Raises :class:`RecordingError` (unreadable file, unknown topic, unsupported type) and
    :class:`~tactus_memory.errors.UnknownSenseError` (a sense the memory does not have).
    """
    recs = [open_recording(p) for p in _paths(paths)]
    if not recs:
        raise RecordingError("no recordings given")
    return IngestJob(memory, recs, session, dict(topics), absolute=absolute, window=window,
                     stride=stride, batch=batch, progress=progress,
                     keep_idle=keep_idle, tf=tf)  # fmt: skip


def ingest_recording(memory: Memory, paths: Any, **kw: Any) -> IngestSummary:
    """Ingest MCAP files / ROS 2 bag folders into ``kw["session"]`` in this process (see the
    module doc; the keywords are :func:`plan_ingest`'s; on Ray:
    :func:`tactus_memory.recordings.ray_jobs.ingest_on_ray`)."""
    return plan_ingest(memory, paths, **kw).run()


def parse_topic_map(pairs: Iterable[str]) -> dict[str, str]:
    """``["/notes=text", "/glove=touch"]`` -> ``{"/notes": "text", "/glove": "touch"}``."""
    out: dict[str, str] = {}
    for p in pairs:
        topic, sep, sense = p.rpartition("=")
        if not sep or not topic or not sense:
            raise RecordingError(f"--topic {p!r}: write TOPIC=SENSE, e.g. /glove/pressure=touch")
        out[topic] = sense
    return out
