"""Recordings in, recordings out: ROS 2 bags and MCAP files into a memory, sessions to Rerun.

    from tactus_memory.recordings.rerun import export_rerun
    from tactus_memory.recordings.ingest import ingest_recording
    ingest_recording(memory, "run1.mcap", session="run1",
                     topics={"/notes": "text", "/glove/pressure": "touch"})
    export_rerun(memory, "run1", "run1.rrd", query="holding a mug")

Also ``ingest_recording(memory, ...)`` / ``export_rerun(memory, ...)`` and the commands
``tactus ingest`` / ``tactus export rerun``. The readers (``mcap``, ``mcap-ros2-support``,
``rosbags``) and ``rerun-sdk`` are the optional extra ``recordings``, imported on use.
"""
