"""Tactus, the touch encoder at run time: the network (``model``), the glove profile and
calibration (``profile``), windows and the idle rule (``windows``), the shipped checkpoint and
its loading (``checkpoint``, ``checkpoints/``, ``configs/``), text targets (``targets``) and heat
maps (``render``). Training and evaluation live in ``tactus_memory.training``."""
