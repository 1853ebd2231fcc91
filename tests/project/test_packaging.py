"""The package installs as one namespace: adapters/ and service/ live under tactus_memory."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_wheel_maps_adapters_and_service_under_tactus_memory(tmp_path: Path) -> None:
    """A non-editable build (what `pip install .` installs) has the mapped layout and data."""
    built = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            # an isolated build: setuptools as pyproject's build-system asks (the one that warns)
            "-v",  # the build backend's own output, where setuptools' warnings go
            "-w",
            str(tmp_path),
            str(ROOT),
        ],
        check=True,
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    (wheel,) = tmp_path.glob("tactus_memory-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "tactus_memory/adapters/__init__.py" in names
    assert "tactus_memory/service/__init__.py" in names
    assert "tactus_memory/service/routers/__init__.py" in names
    assert "tactus_memory/service/static/index.html" in names
    assert "tactus_memory/recordings/ingest.py" in names
    # the data folders ship (issue 26: as packages of their own, so setuptools stays quiet)
    assert "tactus_memory/touch/checkpoints/tactus-lite-minilm.safetensors" in names
    # its ONNX graph, which the default server runs (tactus_memory/export/cache.py)
    assert "tactus_memory/touch/checkpoints/tactus-lite-minilm.onnx" in names
    assert "tactus_memory/touch/checkpoints/tactus-lite-minilm.onnx.json" in names
    assert "tactus_memory/touch/checkpoints/tactus-lite-minilm-demo.onnx" in names
    assert "tactus_memory/touch/checkpoints/tactus-lite-minilm-demo.onnx.json" in names
    # the demo checkpoint (trained without the demo's recordings) and the measured files beside
    # the checkpoints: the demo's held-out figures, the priors and the precision of a match
    for name in ("tactus-lite-minilm-demo.safetensors", "demo-heldout.json"):
        assert f"tactus_memory/touch/checkpoints/{name}" in names
    for name in ("calibration-priors.json", "match-precision.json"):
        assert f"tactus_memory/touch/checkpoints/{name}" in names
        assert f"tactus_memory/spaces/{name}" in names  # the text sense's, by space
    assert "tactus_memory/touch/configs/tactus-lite.json" in names
    assert "tactus_memory/training/queries/stream_queries.json" in names
    assert "tactus_memory/service/static/app.js" in names
    log = built.stdout + built.stderr
    assert "building" in log.lower()  # the backend's output was captured
    assert "is absent from the" not in log, log[-3000:]  # "... the `packages` configuration"
    assert not any(n.startswith(("adapters/", "service/")) for n in names), names
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "tactus = tactus_memory.cli:main" in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_top_level_adapters_and_service_are_not_importable(tmp_path: Path) -> None:
    code = (
        "import importlib.util as u, tactus_memory.adapters as a, tactus_memory.service as s;"
        "assert u.find_spec('adapters') is None and u.find_spec('service') is None;"
        "print(a.__name__, s.__name__)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["tactus_memory.adapters", "tactus_memory.service"]
