"""``tactus ingest --touch NAME=CKPT``: a recording of a 16x16 skin goes into its own touch sense
from the shell; the store records the sense, so the next ingest needs no flag (the sense is
rebuilt from its record). Real MiniLM, real LanceDB, a real MCAP file; the checkpoint is an
untrained tactus-tiny one with the skin's profile (this checks the path, not the model)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.cli.app import app as cli_app
from tactus_memory.memory.main import Memory
from tactus_memory.recordings import samples as rf
from tactus_memory.touch.checkpoint import save_checkpoint
from tactus_memory.touch.model import create_model
from tactus_memory.touch.targets import build_targets
from tests.helpers.sensors import SKIN

pytestmark = pytest.mark.slow

FRAMES = 16  # two 8-frame windows per recording


def _recording(path, seed: int):
    """FRAMES 16x16 raw skin frames (12-bit: rest 2048, a pressed 6x6 patch) as a
    Float32MultiArray topic with layout dims 16x16."""
    rng = np.random.default_rng(seed)
    msgs = []
    for i in range(FRAMES):
        f = np.full(SKIN.shape, 2048.0, np.float32)
        r, c = rng.integers(0, 10, size=2)
        f[r : r + 6, c : c + 6] = 2400.0 + 10 * i
        msgs.append(rf.float32_array("/skin", rf.NS + round(i * rf.NS / rf.GLOVE_HZ), f))
    return rf.write_mcap(path, msgs)


def test_ingest_names_a_touch_sense_once(tmp_path, minilm_space):
    ck = tmp_path / "skin16.safetensors"
    model = create_model("tactus-tiny", out_dim=minilm_space.dim)
    targets = build_targets(minilm_space, ["mug", "pen"])
    save_checkpoint(ck, model, targets, space_dim=minilm_space.dim,
                    calibration=SKIN.to_dict(), steps=0)  # fmt: skip
    data = str(tmp_path / "m")
    runner = CliRunner()
    args = ["ingest", "--data", data, "--topic", "/skin=skin", "--json"]
    first = runner.invoke(cli_app, [*args, str(_recording(tmp_path / "a.mcap", 0)),
                                    "--session", "a", "--touch", f"skin={ck}"])  # fmt: skip
    assert first.exit_code == 0, first.output
    assert json.loads(first.output)["rows"] == {"skin": FRAMES // 8}
    # the store recorded the sense: the next recording needs no --touch
    second = runner.invoke(
        cli_app, [*args, str(_recording(tmp_path / "b.mcap", 1)), "--session", "b"]
    )
    assert second.exit_code == 0, second.output
    assert json.loads(second.output)["rows"] == {"skin": FRAMES // 8}
    bad = runner.invoke(cli_app, [*args, str(tmp_path / "a.mcap"), "--session", "c",
                                  "--touch", "skin"])  # fmt: skip
    assert bad.exit_code != 0 and "NAME=CHECKPOINT" in bad.output
    with Memory.open(data, background=False) as mem:
        info = {s.name: s for s in mem.sense_info()}
        assert info["skin"].shape == [16, 16] and info["skin"].rows == 2 * (FRAMES // 8)
        item = mem.timeline("b")[0]
        assert mem.get_item(item.id).raw.shape == (8, 16, 16)
