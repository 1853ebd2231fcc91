"""Tactus, the touch encoder: STAG data path, models, targets, training, evaluation."""
