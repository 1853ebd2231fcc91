"""Training on your own sensor: the options that say which sensor (``--sensor FILE.toml`` or
``--shape HxW --offset O --span S``) and where its recordings are (``--data FILE.npz`` beside
STAG folders, or ``--bag REC --topic T --labels L``), shared by ``tactus train``, ``pretrain``,
``distill`` and ``eval``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

#: ``--data``: STAG folders / metadata.mat or .npz files of your own sensor
TrainFiles = Annotated[
    list[Path],
    typer.Option(
        "--data",
        help="STAG metadata.mat or folder, or a .npz of your sensor (pressure (N, H, W), "
        "label (N,), recording (N,), optional valid (N,), t (N,)); repeat",
    ),
]
Sensor = Annotated[
    str | None,
    typer.Option(
        "--sensor",
        help="the sensor profile: 'stag-glove' or a TOML file (shape, offset, span, pads, ...); "
        "default stag-glove for STAG files",
    ),
]
Shape = Annotated[
    str | None, typer.Option("--shape", help="instead of --sensor: the frame shape HxW, e.g. 16x16")
]
Offset = Annotated[
    float | None, typer.Option("--offset", help="with --shape: raw reading calibrated to 0")
]
Span = Annotated[
    float | None, typer.Option("--span", help="with --shape: raw counts from 0 to 1 (> 0)")
]
Bags = Annotated[
    list[Path],
    typer.Option("--bag", help="a ROS 2 bag folder or MCAP file to train from; repeat"),
]
Topic = Annotated[
    str | None, typer.Option("--topic", help="with --bag: the tactile topic, e.g. /hand/tactile")
]
Labels = Annotated[
    str | None,
    typer.Option(
        "--labels",
        help="with --bag: a std_msgs/String topic saying what is held: 'mug' from then on, "
        "'' or 'none' for nothing, or 'mug T0 T1' (seconds from the recording's start)",
    ),
]


@dataclass(frozen=True)
class SensorData:
    """Which sensor, and which recordings of it (one group of options)."""

    data: TrainFiles = None  # type: ignore[assignment]
    bag: Bags = None  # type: ignore[assignment]
    topic: Topic = None
    labels: Labels = None
    sensor: Sensor = None
    shape: Shape = None
    offset: Offset = None
    span: Span = None

    def profile(self, default: Any = None) -> Any:
        """The profile the flags name (``default`` when none do); a bad one exits with 2."""
        from tactus_memory.errors import InvalidInputError
        from tactus_memory.touch.profile import STAG_GLOVE
        from tactus_memory.touch.sensor_file import resolve_profile

        try:
            return resolve_profile(
                self.sensor, self.shape, self.offset, self.span, default or STAG_GLOVE
            )
        except InvalidInputError as exc:
            raise typer.BadParameter(str(exc)) from exc

    def load(self, default: Any = None) -> tuple[Any, Any]:
        """(StagData, SensorProfile): the --data files or the --bag recordings, read for the
        profile the flags name (``default`` when none do, else stag-glove)."""
        from tactus_memory.errors import DataFormatError

        profile = self.profile(default)
        data, bags = list(self.data or ()), list(self.bag or ())
        if bool(data) == bool(bags):
            raise typer.BadParameter("give --data FILE... or --bag REC... (one of the two)")
        try:
            if bags:
                if not self.topic or not self.labels:
                    raise typer.BadParameter("--bag needs --topic TACTILE and --labels LABELS")
                from tactus_memory.training.bag_io import load_bags

                return load_bags(bags, self.topic, self.labels, profile), profile
            from tactus_memory.training.train import load_data

            return load_data(data, profile), profile
        except DataFormatError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
