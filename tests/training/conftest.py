"""Fixtures of the training tests: a small synthetic STAG folder in the real file format."""

import pytest

from tests.helpers.stag_synth import make_fields, write_subset


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> list[str]:
    root = tmp_path_factory.mktemp("stag")
    # recording r holds object r % 27: 30 recordings give every object one, three two
    blind = write_subset(root, "blindfolded", make_fields("blindfolded", [10] * 30, seed=1))
    weights = write_subset(root, "weights", make_fields("weights", [10] * 6, seed=2))
    return ["--data", str(blind), "--data", str(weights)]
