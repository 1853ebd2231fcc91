"""The card's own example imports: ``from tactus_memory import TactusEncoder`` and ``from
tactus_memory.adapters import TactusEncoder`` both work and are the same class, and neither
``import tactus_memory`` nor ``import tactus_memory.adapters`` imports torch (fresh
interpreter each, so nothing an earlier test imported counts)."""

from __future__ import annotations

import subprocess
import sys

PROBE = """
import sys
import tactus_memory
import tactus_memory.adapters
assert "torch" not in sys.modules, "import tactus_memory imported torch"
assert "TactusEncoder" in tactus_memory.__all__
from tactus_memory import TactusEncoder
from tactus_memory.adapters import TactusEncoder as FromAdapters
from tactus_memory.adapters.touch import TactusEncoder as Defined
assert TactusEncoder is FromAdapters is Defined, (TactusEncoder, FromAdapters, Defined)
try:
    from tactus_memory.adapters import NoSuchSense  # noqa: F401
except ImportError as e:
    print("refused:", e)
print("ok")
"""


def test_tactus_encoder_imports_from_both_places_lazily() -> None:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "ok"
    assert "refused: cannot import name 'NoSuchSense'" in done.stdout
