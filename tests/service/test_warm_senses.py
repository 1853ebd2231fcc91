"""A server warms every live sense before it answers ready (``Sense.warm``): ``tactus serve``
through ``register_default_senses``, ``tactus mcp`` through its ``warm``; the touch sense's
hook itself: tests/touch/test_caption_vectors.py."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tactus_memory.mcp.server import warm
from tactus_memory.service.app import register_default_senses
from tactus_memory.settings import Settings
from tests.helpers.service import StandInTouch, make_memory


class Warming(StandInTouch):
    """A sense that records each space it is warmed in."""

    def __init__(self, dim: int, name: str) -> None:
        super().__init__(dim, name=name)
        self.warmed: list[Any] = []

    def warm(self, space: Any) -> None:
        self.warmed.append(space)


def test_a_server_warms_every_live_sense_it_serves(tmp_path: Path) -> None:
    memory = make_memory(tmp_path / "mem", touch=False)
    pad, skin = Warming(64, "pad"), Warming(64, "skin")
    memory.add_sense(pad)
    memory.add_sense(skin)
    why = register_default_senses(memory, Settings(touch=False))
    assert why is not None and "disabled" in why  # no touch sense: the others still warmed
    assert pad.warmed == [memory.space] and skin.warmed == [memory.space]
    warm(memory)  # tactus mcp, before its port answers (or behind initialize, over stdio)
    assert pad.warmed == [memory.space] * 2 and skin.warmed == [memory.space] * 2
