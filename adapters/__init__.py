"""Plug-in senses, installed as ``tactus_memory.adapters``: ``adapters.touch.TactusEncoder``
(the touch sense; importing it imports torch). The senses that need no model of their own
(text, image, precomputed vectors) live in :mod:`tactus_memory.senses`.
"""
