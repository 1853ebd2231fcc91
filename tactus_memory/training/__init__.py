"""Training and evaluation of the touch encoder: STAG ``.mat`` reading (``stag_io``, ``data``),
tuples and augmentation, pretraining, training, distillation, evaluation, ablations, the
baseline, metrics and reports. It may import the runtime encoder (``tactus_memory.touch``:
model, profile, windows, checkpoint, targets, render); serving never imports it."""
