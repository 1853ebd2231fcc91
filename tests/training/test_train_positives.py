"""``tactus train --positives contact``: every in-contact frame of a training recording is a
positive; held-out recordings stay out and are still scored on their valid frames only."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.touch.windows import CONTACT_MIN_TAXELS, contact_taxels
from tactus_memory.training.train import holdout_recordings, load_data, prepare_data


def test_contact_positives_on_real_stag(stag_dir) -> None:
    d = load_data([stag_dir / "weights_lite", stag_dir / "blindfolded_lite_train"])
    held = holdout_recordings(d, "one-per-object@blindfolded")
    base = prepare_data(d, held)
    more = prepare_data(d, held, positives="contact")
    is_held = np.isin(d.recording_id, held)
    assert not (more.train_valid & is_held).any()  # held-out frames never trained on
    assert np.array_equal(more.heldout_valid, base.heldout_valid)
    assert (base.train_valid <= more.train_valid).all()  # a superset of the labelled frames
    added = more.train_valid & ~base.train_valid
    assert added.sum() > base.train_valid.sum()  # measured 5,475 more than 2,431
    assert (contact_taxels(d.pressure[added]) >= CONTACT_MIN_TAXELS).all()
    with pytest.raises(ValueError, match="positives"):
        prepare_data(d, held, positives="everything")
