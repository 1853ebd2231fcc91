"""A real small checkpoint pair for the touch tests of issue 22 (re-embedding, grasps on the
real path): synthetic STAG files (tests/helpers/stag_synth.py) and two ``tactus-tiny`` checkpoints
trained by ``tactus train`` (3 steps, seeds 0 and 1) against real MiniLM targets."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from typer.testing import CliRunner

from tests.helpers.stag_synth import make_fields, write_subset


@dataclass(frozen=True)
class Pair:
    a: Path  # checkpoint A (seed 0)
    b: Path  # checkpoint B (seed 1)
    stag: list[Path]  # the STAG subsets they were trained on


def train_pair(root: Path) -> Pair:
    from tactus_memory.cli import app

    blind = write_subset(root, "blindfolded", make_fields("blindfolded", [40] * 6, seed=1))
    out = []
    for seed in (0, 1):
        ck = root / f"tiny-{seed}.safetensors"
        args = ["train", "--data", str(blind), "--out", str(ck), "--model", "tactus-tiny"]
        args += ["--steps", "3", "--batch", "8", "--threads", "1", "--seed", str(seed)]
        r = CliRunner().invoke(app, args)
        assert r.exit_code == 0, (r.output, r.exception)
        out.append(ck)
    return Pair(out[0], out[1], [blind])
