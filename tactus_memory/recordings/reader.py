"""Open a recording (an MCAP file or a ROS 2 bag folder) and read its messages, decoded.

* MCAP files (``*.mcap``, the Foxglove / ROS 2 default): the ``mcap`` library, ROS 2 CDR
  messages decoded by ``mcap-ros2-support``'s decoder.
* ROS 2 bag folders (``metadata.yaml`` + ``*.db3`` or ``*.mcap``, sqlite3 or mcap storage):
  ``rosbags``' ``AnyReader``, message definitions from the bag, else its ROS 2 type store.

Both give the same :class:`Message` (topic, type, log time in ns, the decoded message with
attribute access: ``msg.header.stamp.sec``, ``msg.data``, ...). The optional libraries are
imported lazily: ``pip install tactus-memory[recordings]``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tactus_memory.errors import RecordingError

HASH_CHUNK = 1 << 20  # bytes read at a time for the file digest


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    msgtype: str  # normalised "pkg/msg/Name"
    count: int
    encoding: str = "cdr"


@dataclass(frozen=True)
class Message:
    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


def normalise_type(name: str) -> str:
    """``sensor_msgs/Image`` or ``sensor_msgs/msg/Image`` -> ``sensor_msgs/msg/Image``."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def _missing(lib: str, exc: ImportError) -> ImportError:
    return ImportError(
        f"reading recordings needs {lib} ({exc}); install the extra: "
        "pip install 'tactus-memory[recordings]'"
    )


class Recording:
    """One recording on disk. ``digest`` (sha256 of its bytes) names it in item ids."""

    kind: str

    def __init__(self, path: Path) -> None:
        self.path = path
        self._digest: str | None = None
        self._topics: list[TopicInfo] | None = None

    @property
    def digest(self) -> str:
        if self._digest is None:
            h = hashlib.sha256()
            for f in self._files():
                h.update(f.name.encode())
                with f.open("rb") as fh:
                    while chunk := fh.read(HASH_CHUNK):
                        h.update(chunk)
            self._digest = h.hexdigest()
        return self._digest

    def _files(self) -> list[Path]:
        raise NotImplementedError

    def topics(self) -> list[TopicInfo]:
        """Topics with their type, message count and encoding (read once, then cached)."""
        if self._topics is None:
            self._topics = self._read_topics()
        return list(self._topics)

    def _read_topics(self) -> list[TopicInfo]:
        raise NotImplementedError

    def messages(self, topics: Iterable[str]) -> Iterator[Message]:
        """Messages of these topics in log-time order (file order for unindexed MCAP)."""
        raise NotImplementedError


class McapRecording(Recording):
    kind = "mcap"

    def _files(self) -> list[Path]:
        return [self.path]

    def _reader(self, fh: Any) -> Any:
        try:
            from mcap.reader import make_reader
            from mcap_ros2.decoder import DecoderFactory
        except ImportError as exc:
            raise _missing("mcap and mcap-ros2-support", exc) from exc
        try:
            return make_reader(fh, decoder_factories=[DecoderFactory()])
        except Exception as exc:  # noqa: BLE001  (mcap raises several unrelated types)
            raise RecordingError(f"{self.path} is not a readable MCAP file: {exc}") from exc

    def _read_topics(self) -> list[TopicInfo]:
        with self.path.open("rb") as fh:
            reader = self._reader(fh)
            try:
                summary = reader.get_summary()
            except Exception as exc:  # noqa: BLE001
                raise RecordingError(f"{self.path}: cannot read the MCAP summary: {exc}") from exc
            if summary is not None and summary.statistics is not None:
                counts = summary.statistics.channel_message_counts
                return sorted(
                    (
                        TopicInfo(
                            ch.topic,
                            normalise_type(summary.schemas[ch.schema_id].name)
                            if ch.schema_id in summary.schemas
                            else "",
                            int(counts.get(ch.id, 0)),
                            ch.message_encoding,
                        )
                        for ch in summary.channels.values()
                    ),
                    key=lambda t: t.topic,
                )
            # unindexed (e.g. a recording cut short): count by scanning the records
            found: dict[str, list[Any]] = {}
            try:
                for schema, channel, _ in reader.iter_messages():
                    name = normalise_type(schema.name) if schema else ""
                    entry = found.setdefault(channel.topic, [name, 0, channel.message_encoding])
                    entry[1] += 1
            except Exception as exc:  # noqa: BLE001
                raise RecordingError(f"{self.path}: MCAP file is corrupt: {exc}") from exc
            return [TopicInfo(t, v[0], v[1], v[2]) for t, v in sorted(found.items())]

    def messages(self, topics: Iterable[str]) -> Iterator[Message]:
        wanted = list(topics)
        with self.path.open("rb") as fh:
            reader = self._reader(fh)
            it = reader.iter_decoded_messages(topics=wanted, log_time_order=True)
            while True:
                try:
                    schema, channel, message, decoded = next(it)
                except StopIteration:
                    return
                except Exception as exc:  # noqa: BLE001
                    raise RecordingError(f"{self.path}: MCAP file is corrupt: {exc}") from exc
                yield Message(
                    channel.topic,
                    normalise_type(schema.name if schema else ""),
                    int(message.log_time),
                    decoded,
                )


class BagRecording(Recording):
    kind = "rosbag2"

    def _files(self) -> list[Path]:
        return sorted(p for p in self.path.iterdir() if p.is_file())

    def _open(self) -> Any:
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError as exc:
            raise _missing("rosbags", exc) from exc
        store = getattr(Stores, "LATEST", Stores.ROS2_HUMBLE)
        reader = AnyReader([self.path], default_typestore=get_typestore(store))
        try:
            reader.open()
        except Exception as exc:  # noqa: BLE001  (rosbags raises its own error types)
            raise RecordingError(f"{self.path} is not a readable ROS 2 bag: {exc}") from exc
        return reader

    def _read_topics(self) -> list[TopicInfo]:
        reader = self._open()
        try:
            by: dict[str, TopicInfo] = {}
            for c in reader.connections:
                prev = by.get(c.topic)
                n = int(c.msgcount) + (prev.count if prev else 0)
                by[c.topic] = TopicInfo(c.topic, normalise_type(c.msgtype), n, "cdr")
            return [by[t] for t in sorted(by)]
        finally:
            reader.close()

    def messages(self, topics: Iterable[str]) -> Iterator[Message]:
        wanted = set(topics)
        reader = self._open()
        try:
            conns = [c for c in reader.connections if c.topic in wanted]
            if not conns:
                return
            it = reader.messages(connections=conns)
            while True:
                try:
                    conn, stamp, raw = next(it)
                    msg = reader.deserialize(raw, conn.msgtype)
                except StopIteration:
                    return
                except Exception as exc:  # noqa: BLE001
                    raise RecordingError(f"{self.path}: ROS 2 bag is corrupt: {exc}") from exc
                yield Message(conn.topic, normalise_type(conn.msgtype), int(stamp), msg)
        finally:
            reader.close()


def open_recording(path: str | Path) -> Recording:
    """An MCAP file or a ROS 2 bag folder; :class:`RecordingError` for anything else."""
    p = Path(path)
    if p.is_dir():
        if not (p / "metadata.yaml").is_file():
            raise RecordingError(f"{p} is a folder without metadata.yaml: not a ROS 2 bag")
        return BagRecording(p)
    if not p.is_file():
        raise RecordingError(f"no recording at {p}")
    if p.suffix == ".db3" or (p.parent / "metadata.yaml").is_file():
        raise RecordingError(f"{p} is a file inside a ROS 2 bag; pass the bag folder {p.parent}")
    return McapRecording(p)
