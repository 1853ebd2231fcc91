"""Serving needs no PyTorch: torch, sentence-transformers and the torch export are the ``train``
extra; the server, a search and a touch write run on ONNX Runtime without them. Nor pandas:
where it is installed pyarrow imports it into the server (~49 MB resident), so serving does
not install it (the ray extra brings it).

Two halves, each cheap:

* what ``pip install tactus-memory[recordings,mcp]`` would pull: the package's own base and
  serving requirements, followed through the installed distributions' metadata as pip's resolver
  walks them, never reach torch (a full ``pip install --dry-run`` into a fresh venv gives the
  same answer but takes over a minute on 2 cores: see the closing note of the issue);
* a real ``pip install`` of the serving set into a fresh venv in which torch is NOT installed:
  the venv sees the test venv's packages less torch, sentence-transformers, transformers, pandas
  and this package (links, no copy: the dependencies are there as a warm wheel cache would
  give them), then pip itself, offline (``--no-index``), resolves ``tactus-memory[recordings,
  mcp]`` from a copy of the checkout against them and builds and installs the package (not
  editable: the wheel's own files, the shipped touch graph and the browser page included). A
  requirement that needed torch, or anything else not linked, fails the install. Its
  ``tactus serve`` exports MiniLM from the safetensors weights into an empty user cache (no
  torch anywhere), then answers the README tour's touch write, note and search.

Installing every dependency from wheels (unpacking ~1.9 GB) costs minutes on 2 cores
(``benchmarks/make_run.py`` measures it as a newcomer's ``make run``): this test installs the
package itself for real and the dependencies as links.
"""

from __future__ import annotations

import importlib.metadata as md
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import httpx
import numpy as np
import pytest
from packaging.requirements import Requirement

from benchmarks.serving import copy_checkout, free_port, start_serve, stop_process, wait_ok

#: what only the train extra may bring
TORCH_SIDE = {"torch", "sentence-transformers", "transformers", "triton"}
#: what serving must not install: the torch side, and pandas (pyarrow would import it)
NOT_SERVING = TORCH_SIDE | {"pandas"}
#: the extras `make run` installs (Makefile), besides the base
SERVING_EXTRAS = ("recordings", "mcp")
#: how long a server may take to answer /ready here (only a server that never starts fails)
READY_S = 600
ROOT = Path(__file__).resolve().parents[2]
#: the interpreter never puts the working folder (the checkout, whose tactus_memory/ would
#: shadow the installed package) on sys.path (Python 3.11+)
SAFE_PATH = {"PYTHONSAFEPATH": "1"}


def _norm(name: str) -> str:
    return name.lower().replace("_", "-")


def _pulled(extras: tuple[str, ...]) -> set[str]:
    """Every distribution the package's base (and ``extras``) requires, transitively, through
    the installed metadata; markers are evaluated as pip does (extras of dependencies only as
    they are asked for)."""
    seen: set[str] = set()
    todo: list[tuple[str, frozenset[str]]] = [("tactus-memory", frozenset(extras))]
    while todo:
        name, wanted = todo.pop()
        try:
            reqs = md.requires(name) or []
        except md.PackageNotFoundError:
            continue  # not installed here (a platform marker's package): nothing to follow
        for line in reqs:
            req = Requirement(line)
            envs = [{"extra": e} for e in wanted] or [{"extra": ""}]
            if req.marker is not None and not any(req.marker.evaluate(env) for env in envs):
                continue
            dep = _norm(req.name)
            key = f"{dep}[{','.join(sorted(req.extras))}]"
            if key in seen:
                continue
            seen.add(key)
            todo.append((dep, frozenset(req.extras)))
    return {k.split("[")[0] for k in seen}


def test_the_serving_install_never_pulls_torch() -> None:
    serving = _pulled(SERVING_EXTRAS)
    assert {"lancedb", "onnxruntime", "tokenizers", "mcp", "fastapi"} <= serving
    assert serving.isdisjoint(NOT_SERVING), serving & NOT_SERVING
    # and the train extra (which make test installs) is where they are
    assert {"torch", "sentence-transformers"} <= _pulled(("train",))


@pytest.fixture(scope="module")
def torchless_python(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A fresh venv's interpreter into which pip installed ``tactus-memory[recordings,mcp]``
    (offline, from a copy of the checkout), seeing this venv's packages less the torch side
    and this package."""
    root = tmp_path_factory.mktemp("torchless")
    source = root / "source"
    copy_checkout(ROOT, source)  # the build writes build/ and *.egg-info beside the sources
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    shadow = root / "site"
    shadow.mkdir()
    here = Path(sysconfig.get_paths()["purelib"])
    for entry in here.iterdir():
        top = _norm(entry.name.split("-")[0] if entry.name.endswith("-info") else entry.name)
        if top in NOT_SERVING or top in {"functorch", "torchgen", "tactus-memory"}:
            continue
        if entry.name.startswith("__editable__"):  # this checkout's editable install
            continue
        (shadow / entry.name).symlink_to(entry)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "shadow.pth").write_text(f"import site; site.addsitedir({str(shadow)!r})\n")
    # this venv's pip installs into the fresh one (--python): no index, no download, the
    # build backend (setuptools) from the links, no byte-compiling (as make run installs)
    pip = [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-index"]
    pip += ["--no-build-isolation", "--no-compile", "--progress-bar", "off"]
    done = subprocess.run(
        [*pip, f"{source}[{','.join(SERVING_EXTRAS)}]"], capture_output=True, text=True, cwd=root
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "Successfully installed tactus-memory-" in done.stdout, done.stdout[-2000:]
    check = (
        "import importlib.util as u, tactus_memory; "
        "print(u.find_spec('torch'), u.find_spec('pandas'), tactus_memory.__file__)"
    )
    out = subprocess.run(
        [str(python), "-c", check],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
        env={**os.environ, **SAFE_PATH},
    )
    # torch and pandas are not importable; the package is the installed one, not the checkout
    assert out.stdout.startswith("None None "), out
    assert out.stdout.split()[-1].startswith(site), out
    return str(python)


@pytest.mark.slow
def test_the_tour_server_runs_without_torch(torchless_python: str, tmp_path: Path) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp_path / "serve.log"
    env = {"TACTUS_CACHE": str(tmp_path / "cache"), "HF_HUB_OFFLINE": "1", **SAFE_PATH}
    proc = start_serve(port, tmp_path / "memory", log, env=env, python=torchless_python)
    try:
        assert wait_ok(proc, base + "/ready", READY_S, interval=0.2) is not None, log.read_text()
        raw = np.full((8, 32, 32), 512, np.int16)
        raw[:, 10:22, 8:20] = 700
        with httpx.Client(base_url=base, timeout=60) as c:
            touch = c.post("/sessions/a/touch", json={"frames": raw.tolist(), "t": 1.0})
            assert touch.status_code == 201, touch.text
            note = c.post("/sessions/a/text", json={"text": "holding a red mug", "t": 2.0})
            assert note.status_code == 201, note.text
            hits = c.get("/search", params={"q": "red mug", "k": 5}).json()["hits"]
            touch_hits = c.get("/search", params={"q": "grasp", "sense": "touch"}).json()["hits"]
        assert hits and hits[0]["text"] == "holding a red mug"
        assert touch_hits and touch_hits[0]["sense"] == "touch"
        maps = Path(f"/proc/{proc.pid}/maps").read_text()
        assert "onnxruntime" in maps and "libtorch" not in maps and "/pandas/" not in maps
    finally:
        stop_process(proc)
    # the export wrote its check: MiniLM against the shipped reference vectors, no torch
    checked = list((tmp_path / "cache").rglob("checked.json"))
    assert len(checked) == 1 and '"torch": false' in checked[0].read_text()
    assert "Traceback" not in log.read_text()
    assert os.path.getsize(checked[0].parent / "minilm.onnx.data") > 80_000_000
