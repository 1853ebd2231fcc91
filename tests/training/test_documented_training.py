"""Every training command the docs show runs as written into a folder that does not exist yet
(``--out runs/x.safetensors`` with no ``runs/``), at a tiny size: the docs' data options
become the synthetic five-pad hand's ``.npz`` and profile, the steps a handful. A command that
fails says it in one line on stderr and exits 2 (no traceback)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.cli import app
from tests.helpers.hand_synth import as_arrays, recordings, write_toml
from tests.helpers.progress import assert_bar_finished

pytestmark = pytest.mark.slow

DOCS = Path(__file__).resolve().parents[2] / "docs"
#: the training commands (``tactus baseline train`` reads STAG .mat files only: run on them in
#: tests/training, not here; ``--bag`` runs from a bag: tests/training/test_own_sensor_training.py)
COMMAND = re.compile(r"^tactus (pretrain|train|distill)\b")
#: a CI-sized run of any of them
TINY = {"--steps": "2", "--batch": "8", "--model": "tactus-tiny", "--threads": "1"}
#: options that name a GPU or another space's model: dropped (the run is on this CPU, MiniLM)
DROPPED = {"--device": 1, "--space": 1, "--space-path": 1, "--augment": 1, "--resume": 0}


def documented() -> list[tuple[str, str]]:
    """(page, command line) of every training command in a ``bash`` block of the docs."""
    found = []
    for page in sorted(DOCS.rglob("*.md")):
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = line.split("  #")[0].strip()
                if COMMAND.match(line) and "--bag" not in line:
                    found.append((page.name, line))
    return found


def as_run(line: str, folder: Path, data: list[str]) -> list[str]:
    """The documented ``line`` as arguments for this test: its data, a tiny size, its outputs
    under ``folder`` (which does not exist yet)."""
    line = re.sub(r"\[(--teacher [^\]]+)\]", r"\1", line)  # an optional teacher: given
    words = shlex.split(line.replace("$D", "").replace("$H", ""))[1:]
    args: list[str] = []
    i = 0
    while i < len(words):
        w = words[i]
        if w in DROPPED:
            i += 1 + DROPPED[w]
            continue
        if w in TINY or w in ("--data", "--sensor", "--holdout", "--epochs"):
            i += 2  # the docs' value is replaced below
            continue
        if "runs/" in w:
            w = str(folder / w[w.index("runs/") :])
        args.append(w)
        i += 1
    for flag, value in TINY.items():
        args += [flag, value]
    return [*args, *data]


def test_the_docs_show_the_training_commands() -> None:
    kinds = {line.split()[1] for _, line in documented()}
    assert kinds == {"pretrain", "train", "distill"}, documented()


def test_every_documented_training_command_runs_into_a_new_folder(tmp_path: Path) -> None:
    hand_dir = tmp_path / "hand"
    hand_dir.mkdir()
    npz = hand_dir / "hand.npz"
    profile = write_toml(hand_dir)
    np.savez(npz, **as_arrays(recordings(_profile(profile), per_object=2, frames=16, seed=0)))
    data = ["--data", str(npz), "--sensor", str(profile), "--holdout", "one-per-object@"]
    runner = CliRunner()
    ran: list[str] = []
    # pretrain, then train, then distill: what each names as its input is written first
    order = {"pretrain": 0, "train": 1, "distill": 2}
    done: set[tuple[str, ...]] = set()
    for page, line in sorted(documented(), key=lambda pl: order[pl[1].split()[1]]):
        folder = tmp_path / "new" / str(len(ran))  # a folder that does not exist yet
        args = as_run(line, folder, data)
        # the same command as one already run but for the names of its files: run once
        same = tuple(sorted(a for a in args if not a.endswith(".safetensors")))
        ran.append(line)
        if same in done:
            continue
        done.add(same)
        for i, a in enumerate(args):
            if a.endswith(".safetensors") and args[i - 1] in ("--pretrained", "--teacher"):
                args[i] = str(_made(tmp_path, "mae" if args[i - 1] == "--pretrained" else "touch"))
        assert not folder.exists()
        r = runner.invoke(app, args)
        assert r.exit_code == 0, (page, line, args, r.output[-2000:], r.exception)
        out = Path(args[args.index("--out") + 1])
        assert out.is_file() and out.parent == folder / "runs", (page, line)
        # the steps done, with the time left (tqdm's bar on stderr; distill trains as train)
        kind = line.split()[1]
        assert_bar_finished(r.stderr, "mae" if kind == "pretrain" else "train")
        _remember(tmp_path, line.split()[1], out)
    assert len(ran) == len(documented()) and len(done) == 3


def test_a_failing_command_is_one_line_and_exit_2(tmp_path: Path) -> None:
    r = CliRunner().invoke(
        app, ["pretrain", "--data", str(tmp_path / "none.npz"), "--out", str(tmp_path / "x/m")]
    )
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and len(r.output.strip().splitlines()) <= 6


def _profile(path: Path):
    from tactus_memory.touch.sensor_file import load_profile_toml

    return load_profile_toml(path)


def _remember(tmp_path: Path, kind: str, out: Path) -> None:
    name = {"pretrain": "mae", "train": "touch"}.get(kind)
    if name and not (tmp_path / f"{name}.path").exists():
        (tmp_path / f"{name}.path").write_text(str(out))


def _made(tmp_path: Path, name: str) -> Path:
    return Path((tmp_path / f"{name}.path").read_text())
