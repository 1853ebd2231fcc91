"""Recordings in, recordings out: ROS 2 bags and MCAP files into a memory, sessions to Rerun.

    from tactus_memory.recordings import ingest_recording, export_rerun
    ingest_recording(memory, "run1.mcap", session="run1",
                     topics={"/notes": "text", "/glove/pressure": "touch"})
    export_rerun(memory, "run1", "run1.rrd", query="holding a mug")

Also ``memory.ingest_recording(...)`` / ``memory.export_rerun(...)`` and the commands
``tactus ingest`` / ``tactus export rerun``. The readers (``mcap``, ``mcap-ros2-support``,
``rosbags``) and ``rerun-sdk`` are the optional extra ``recordings``, imported on use.
"""

from __future__ import annotations

from tactus_memory.recordings.export import ExportSummary, export_rerun
from tactus_memory.recordings.ingest import (
    IngestSummary,
    TopicListing,
    ingest_recording,
    list_topics,
    parse_topic_map,
)
from tactus_memory.recordings.reader import RecordingError, open_recording

__all__ = [
    "ExportSummary",
    "IngestSummary",
    "RecordingError",
    "TopicListing",
    "export_rerun",
    "ingest_recording",
    "list_topics",
    "open_recording",
    "parse_topic_map",
]
