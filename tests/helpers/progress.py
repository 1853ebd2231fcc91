"""The progress bar a long CLI job draws on stderr (tqdm's ``done/total [elapsed<left``)."""

from __future__ import annotations

import re


def assert_bar_finished(stderr: str, desc: str) -> None:
    """``stderr`` shows the bar named ``desc`` at its total, with the elapsed and the time
    left (tqdm rewrites the line with ``\\r``: every state is one of its parts)."""
    bar = re.compile(rf"{re.escape(desc)}.*\| (\S+)/\1 \[\d\d:\d\d<\d\d:\d\d")
    states = re.split(r"[\r\n]", stderr)
    assert any(bar.search(s) for s in states), f"no finished {desc!r} bar on stderr:\n{stderr}"
