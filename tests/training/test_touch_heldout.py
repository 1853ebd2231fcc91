"""The held-out gate for touch (issue 16): a small Tactus model trained here, on the real STAG
files, with the shipped recipe's validation split (``one-per-object@blindfolded``: one
blindfolded recording per object never seen in training), must rank the 27 object phrases
well above chance on those recordings. A regression in the data path, the targets, the
augmentation or the loop makes it fail; the shipped model's own check is in-sample.

Cost: ``tactus-tiny``, 150 steps of 32 windows on 2 threads (~100 CPU-seconds: about a
minute on a quiet 2-core machine, 4 minutes measured on a heavily shared one; the shipped
settings take ~4 minutes even on a quiet one)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch

STEPS, BATCH = 150, 32
CHANCE = 1 / 27
#: measured with exactly this recipe (seed 0, 2 threads): held-out top-1 0.223, top-3 0.431
#: on the 26 held-out recordings; the bounds sit below with margin (4x and 8x chance)
HELDOUT_MIN, HELDOUT_TOP3_MIN = 0.15, 0.30


@pytest.fixture(scope="module")
def heldout_summary(stag_dir: Path, minilm_space, tmp_path_factory) -> dict[str, Any]:
    from tactus_memory.touch.targets import build_targets
    from tactus_memory.training.train import (
        TrainConfig,
        fit,
        holdout_recordings,
        load_data,
        prepare_data,
    )

    d = load_data([stag_dir / "weights_lite", stag_dir / "blindfolded_lite_train"])
    td = prepare_data(d, holdout_recordings(d, "one-per-object@blindfolded"))
    targets = build_targets(minilm_space, td.classes)
    cfg = TrainConfig(
        model="tactus-tiny",
        steps=STEPS,
        batch=BATCH,
        warmup=max(1, min(150, STEPS // 20)),  # as `tactus train` sets it
        save_every=10_000,
    )
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        out = tmp_path_factory.mktemp("heldout") / "tiny.safetensors"
        return fit(td, targets, cfg, out, space_dim=minilm_space.dim, device="cpu", progress=False)
    finally:
        torch.set_num_threads(threads)


@pytest.mark.slow
def test_small_model_generalises_to_heldout_recordings(heldout_summary) -> None:
    h = heldout_summary["heldout"]
    print("held-out:", {k: h[k] for k in ("top1", "top3", "recordings") if k in h})
    assert heldout_summary["steps"] == STEPS
    assert h["recordings"] == 26  # one blindfolded recording per object (26 of 27 have one)
    assert h["top1"] >= HELDOUT_MIN > 2 * CHANCE, h["top1"]
    assert h["top3"] >= max(h["top1"], HELDOUT_TOP3_MIN), h["top3"]
