"""Fixtures of the service tests: a memory in tmp_path and a TestClient over it."""

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.sensors import stag, windows  # noqa: F401  (the sensor tests' STAG fixtures)
from tests.helpers.service import DIM, FRAMES, make_memory


@pytest.fixture
def memory(tmp_path):
    return make_memory(tmp_path / "mem")


@pytest.fixture
def client(memory):
    with TestClient(create_app(Settings(max_body_bytes=2 * 1024 * 1024), memory=memory)) as c:
        yield c


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    import torch

    from tactus_memory.touch.checkpoint import save_checkpoint
    from tactus_memory.touch.model import create_model
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.targets import build_targets
    from tests.helpers.fakes import HashingSpace
    from tests.helpers.stag_synth import OBJECTS

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "tiny.safetensors"
    model = create_model("tactus-tiny", out_dim=DIM, frames=FRAMES)
    targets = build_targets(HashingSpace(dim=DIM), OBJECTS)
    save_checkpoint(path, model, targets, space_dim=DIM, calibration=STAG_GLOVE.to_dict())
    return path
