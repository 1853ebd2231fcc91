"""Text targets: phrases, centring geometry, query transform, centroid in the checkpoint."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint
from tactus_memory.touch.model import create_model
from tactus_memory.touch.targets import (
    build_targets,
    centre,
    class_phrases,
    geometry,
    natural_name,
    target_report,
)
from tests.helpers.stag_synth import OBJECTS


def test_natural_names_and_phrases() -> None:
    assert natural_name("screw_driver") == "screwdriver"
    assert natural_name("some_new_thing") == "some new thing"
    assert class_phrases("mug")[0] == "a human hand firmly grasping a mug"
    assert class_phrases("allen_key_set")[0].endswith("a set of allen keys")
    assert class_phrases("empty_can")[0].endswith("an empty soda can")
    empty = class_phrases("empty_hand")
    assert all("grasping" not in p for p in empty) and len(empty) == len(class_phrases("mug"))
    assert all("_" not in p for c in OBJECTS for p in class_phrases(c))


def test_centring_spreads_targets(hashing_space) -> None:
    t = build_targets(hashing_space, OBJECTS)
    rep = target_report(t)
    assert rep["before"]["mean_offdiag_cos"] > rep["after"]["mean_offdiag_cos"] + 0.1
    # centred C unit vectors summing to ~0 reach the minimum mean cosine -1/(C-1)
    assert rep["after"]["mean_offdiag_cos"] == pytest.approx(-1 / (len(OBJECTS) - 1), abs=0.01)
    assert rep["after"]["nearest_distractor_margin"] > rep["before"]["nearest_distractor_margin"]
    assert np.allclose(np.linalg.norm(t.centred, axis=1), 1.0, atol=1e-5)
    q = hashing_space.embed_texts(["holding a screwdriver"], query=True)
    assert np.allclose(t.query_transform(q), centre(q, t.centroid))
    assert np.allclose(np.linalg.norm(t.query_transform(q), axis=1), 1.0, atol=1e-5)


def test_geometry_of_orthonormal_rows() -> None:
    g = geometry(np.eye(4, dtype=np.float32))
    assert g["mean_offdiag_cos"] == pytest.approx(0.0)
    assert g["nearest_distractor_margin"] == pytest.approx(1.0)


def test_centroid_round_trips_through_checkpoint(tmp_path, hashing_space) -> None:
    t = build_targets(hashing_space, OBJECTS[:5])
    model = create_model("tactus-tiny", out_dim=hashing_space.dim)
    save_checkpoint(tmp_path / "c.safetensors", model, t, space_dim=hashing_space.dim)
    ck = load_checkpoint(tmp_path / "c.safetensors")
    assert np.array_equal(ck.targets.centroid, t.centroid)
    assert np.array_equal(ck.targets.centred, t.centred)
    assert ck.classes == OBJECTS[:5] and ck.space_name == "fake-hash" and ck.dim == 64
    assert isinstance(ck.model.trunk.stem[0].weight, torch.Tensor)


@pytest.mark.slow
def test_minilm_target_geometry(minilm_space) -> None:
    """Measured in MiniLM (paper's space: 0.504/0.354 -> -0.038/0.777)."""
    rep = target_report(build_targets(minilm_space, OBJECTS))
    print("MiniLM target geometry:", rep)
    assert rep["before"]["mean_offdiag_cos"] > 0.3
    assert rep["after"]["mean_offdiag_cos"] < 0.0
    assert rep["after"]["nearest_distractor_margin"] > rep["before"]["nearest_distractor_margin"]
