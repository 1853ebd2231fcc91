"""Fixtures of the service tests: a memory in tmp_path and a TestClient over it."""

import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory


@pytest.fixture
def memory(tmp_path):
    return make_memory(tmp_path / "mem")


@pytest.fixture
def client(memory):
    with TestClient(create_app(Settings(max_body_bytes=2 * 1024 * 1024), memory=memory)) as c:
        yield c
