"""``tactus ingest`` (MCAP files, ROS 2 bags -> a session) and ``tactus export rerun``.

    tactus ingest run1.mcap --list
    tactus ingest run1.mcap --session run1 --topic /notes=text --topic /glove/pressure=touch
    tactus export rerun run1 --out run1.rrd --query "holding a mug"

The memory is ``--data`` (else $TACTUS_DATA, else ./memory; created when missing). Senses a
topic maps to are registered like ``tactus serve`` does: touch with the shipped checkpoint,
image when the space has vision.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    MemoryData,
    RayJob,
    TouchSenses,
    TouchStride,
    TouchWindow,
)
from tactus_memory.cli.memory_cmds import _data_dir, _open, _print_json, _print_results
from tactus_memory.cli.space_opts import fail
from tactus_memory.recordings.rerun import export_rerun
from tactus_memory.signatures import grouped

if TYPE_CHECKING:
    from tactus_memory.memory.main import Memory

export_app = typer.Typer(help="Export a session to a viewer's format.", no_args_is_help=True)
app.add_typer(export_app, name="export")


def _memory_for(
    data: str | None, senses: set[str], touch_senses: dict[str, str] | None = None
) -> Memory:
    """The memory with the senses the topics map to: the touch senses named with ``--touch
    NAME=CKPT``, those the store records (rebuilt from their record, e.g. a sensor that
    ``tactus serve --touch`` registered), then the defaults still missing."""
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory

    memory = Memory.open(_data_dir(data))
    for name, checkpoint in (touch_senses or {}).items():
        memory.add_sense(TactusEncoder(checkpoint, name=name))
    recorded = {s.name for s in memory.sense_info()}
    wanted = senses - set(memory.senses)
    if wanted & recorded:
        for name, why in memory.restore_senses(skip=recorded - wanted).items():
            typer.echo(f"sense {name!r} cannot be rebuilt: {why}", err=True)
    if "touch" in senses and "touch" not in memory.senses:
        memory.add_sense(TactusEncoder())
    if (
        "image" in senses
        and "image" not in memory.senses
        and getattr(memory.space, "has_vision", False)
    ):
        from tactus_memory.adapters.image import ImageSense

        memory.add_sense(ImageSense(memory.space))
    return memory


def _touch_senses(pairs: list[str] | None) -> dict[str, str]:
    from tactus_memory.service.startup import (
        StartupError,
        check_touch_senses,
        parse_touch_senses,
    )

    try:
        named = parse_touch_senses(pairs or [])
        check_touch_senses(named)
        return named
    except StartupError as exc:
        fail(str(exc))
        raise  # unreachable: fail exits


@app.command("ingest")
@grouped(ray=RayJob)
def ingest(
    files: Annotated[
        list[Path], typer.Argument(help="MCAP files and/or ROS 2 bag folders.", exists=True)
    ],
    session: Annotated[str | None, typer.Option("--session", help="Session id to fill.")] = None,
    topic: Annotated[
        list[str] | None,
        typer.Option(
            "--topic",
            help="TOPIC=SENSE, repeatable (e.g. /glove/pressure=touch); TOPIC=pose for the "
            "trajectory (Odometry, PoseStamped, or /tf with --tf).",
        ),
    ] = None,
    tf: Annotated[
        str,
        typer.Option("--tf", help="PARENT->CHILD transform read from a TFMessage pose topic."),
    ] = "map->base_link",
    touch: TouchSenses = None,
    data: MemoryData = None,
    absolute: Annotated[
        bool, typer.Option("--absolute", help="Unix times instead of the session clock.")
    ] = False,
    list_only: Annotated[
        bool, typer.Option("--list", help="Print topics, types, counts, default senses.")
    ] = False,
    window: TouchWindow = None,
    stride: TouchStride = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    *,
    ray: RayJob,
) -> None:
    """Ingest ROS 2 bags / MCAP files: text (std_msgs/String), touch (mono16/16UC1/mono8/32FC1
    Images, Int16/Float32MultiArray), images (rgb8/bgr8, CompressedImage), the trajectory
    (=pose: Odometry, PoseStamped, TFMessage). Safe to re-run. --ray: as Ray Data jobs."""
    from tactus_memory.errors import TactusError
    from tactus_memory.recordings.ingest import ingest_recording, list_topics, parse_topic_map

    try:
        if list_only:
            _print_results(
                list_topics(files),
                as_json=as_json,
                title="topics",
                columns=("file", "topic", "type", "count", "sense"),
                row=lambda r: (r.file, r.topic, r.type, str(r.count), r.sense or "-"),
            )
            return
        if not session:
            fail("--session is required (or --list to see the topics)")
        if not topic:
            fail("map topics with --topic TOPIC=SENSE (see --list for the topics)")
        topics = parse_topic_map(topic)
        parent, arrow, child = tf.partition("->")
        if not arrow or not parent.strip() or not child.strip():
            fail(f"--tf {tf!r}: write PARENT->CHILD, e.g. map->base_link")
        address = ray.cluster()
        memory = _memory_for(data, set(topics.values()), _touch_senses(touch))
        kw = {"session": session, "topics": topics, "absolute": absolute, "window": window,
              "stride": stride, "tf": (parent.strip(), child.strip())}  # fmt: skip
        if address is None:
            summary = ingest_recording(memory, files, progress=not as_json, **kw)
        else:
            from tactus_memory.recordings.ray_jobs import ingest_on_ray

            summary = ingest_on_ray(memory, files, address=address, workers=ray.ray_workers, **kw)
    except (TactusError, ImportError) as exc:
        fail(str(exc))  # exits
    if as_json:
        _print_json(summary.model_dump())
        return
    rows_txt = ", ".join(f"{k}: {v}" for k, v in sorted(summary.rows.items())) or "none"
    typer.echo(
        f"session {summary.session}: {summary.messages} messages, new rows {rows_txt}, "
        f"already present {summary.existing} ({summary.messages_per_s:.0f} msg/s, "
        f"{summary.rows_per_s:.1f} rows/s)"
    )
    for name, n in sorted(summary.poses.items()):
        typer.echo(f"  poses from {name}: {n}" + (" (stored before)" if n == 0 else ""))
    for reason, n in sorted(summary.skipped.items()):
        typer.echo(f"  skipped {n}: {reason}")


@export_app.command("rerun")
def export_rerun_cmd(
    session: Annotated[str, typer.Argument(help="Session id.")],
    out: Annotated[Path, typer.Option("--out", help="The .rrd file to write.")],
    query: Annotated[
        str | None, typer.Option("--query", help="Annotate the moments of this query.")
    ] = None,
    data: MemoryData = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Write a session as a Rerun recording: touch heat maps, notes, query moments."""
    from tactus_memory.errors import TactusError

    memory = _open(data)  # exits when there is no memory there
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        summary = export_rerun(memory, session, out, query=query)
    except (TactusError, ImportError) as exc:
        fail(str(exc))  # exits
    if as_json:
        _print_json(summary.model_dump())
        return
    typer.echo(
        f"wrote {summary.path}: "
        + ", ".join(f"{k} {v}" for k, v in sorted(summary.entities.items()))
        + f"; {summary.moments} moments"
    )
