"""Helpers for the browser tests (no tests here): a real uvicorn server, Debian's Chromium
through Python Playwright, real STAG touch windows.

The server runs in a subprocess (``python -m tests.helpers.browser serve ...``): uvicorn on
127.0.0.1 at a free port, the real MiniLM space, a LanceDB store under the test's tmp dir,
and the shipped ``TactusEncoder`` (no stand-in fallback: a checkpoint that does not load
fails the server start). It writes which encoder it used to ``touch.json`` beside the store.

Chromium is Debian's package (``apt-get install -y chromium``: /usr/bin/chromium), driven by
the ``playwright`` PyPI package's driver with ``executable_path``; Playwright's own browser
download (``playwright install``) is never used.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.serving import free_port
from tests.helpers.servers import STARTUP_S, stop_process, wait_healthy

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("TACTUS_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
INSTALL_HINT = (
    "install Debian's Chromium: `apt-get update && apt-get install -y chromium` "
    "(or point TACTUS_CHROMIUM at a Chromium binary), and the Python driver: "
    "`pip install playwright` (never `playwright install`)"
)
VIEWPORT = {"width": 1366, "height": 768}


# ----------------------------------------------------------------------------- chromium
def chromium_path() -> str:
    """The Chromium binary, or FAIL (not skip): CI installs it, so absence is a broken setup."""
    path = CHROMIUM if os.path.isabs(CHROMIUM) else shutil.which(CHROMIUM)
    if not path or not os.access(path, os.X_OK):
        pytest.fail(f"Chromium not found at {CHROMIUM!r}: {INSTALL_HINT}", pytrace=False)
    return path


def sync_playwright() -> Any:
    try:
        from playwright.sync_api import sync_playwright as sp
    except ImportError:
        pytest.fail(f"the playwright package is missing: {INSTALL_HINT}", pytrace=False)
    return sp()


def launch(pw: Any, profile_dir: Path) -> Any:
    """A persistent context on a fresh, empty user-data dir, laptop-sized viewport."""
    profile_dir.mkdir(parents=True, exist_ok=True)
    return pw.chromium.launch_persistent_context(
        str(profile_dir),
        executable_path=chromium_path(),
        headless=True,
        args=[a for a in CHROMIUM_ARGS if a != "--headless"],  # headless=True adds it
        viewport=VIEWPORT,
        reduced_motion="reduce",
    )


@contextmanager
def ready_page(base: str, profile_dir: Path, timeout_ms: int) -> Iterator[tuple[Any, list[str]]]:
    """Chromium on a fresh profile (:func:`launch`), one tab on the page at ``base`` once it
    says it is ready: ``(page, errors)``, ``errors`` the JavaScript errors it raises."""
    with sync_playwright() as pw:
        context = launch(pw, profile_dir)
        try:
            page = context.new_page()
            page.set_default_timeout(timeout_ms)
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(base + "/")
            page.wait_for_selector("body[data-ready=true]")
            yield page, errors
        finally:
            context.close()


# ----------------------------------------------------------------------------- server
class Server:
    """``python -m tests.helpers.browser serve`` in a subprocess; ``base`` is its URL."""

    def __init__(self, data: Path, log: Path, *, token: str | None = None) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.data = data
        self.log = log
        cmd = [sys.executable, "-m", "tests.helpers.browser", "serve", "--data", str(data)]
        cmd += ["--port", str(self.port)] + (["--token", token] if token else [])
        env = {**os.environ, "OMP_NUM_THREADS": "1", "TOKENIZERS_PARALLELISM": "false"}
        self.proc = subprocess.Popen(
            cmd, cwd=ROOT, stdout=log.open("ab"), stderr=subprocess.STDOUT, env=env
        )
        wait_healthy(self.proc, self.base, STARTUP_S, self.tail, self.stop)

    @property
    def touch_encoder(self) -> str:
        return json.loads((self.data.parent / "touch.json").read_text())["touch"]

    def tail(self) -> str:
        return self.log.read_text(errors="replace")[-3000:]

    def stop(self) -> None:
        stop_process(self.proc)


def add_notes(c: Any, session: str, notes: list[tuple[float, str]]) -> dict[str, str]:
    """POST each ``(t, text)`` note to ``session`` with the httpx client ``c``; text -> id."""
    ids = {}
    for t, text in notes:
        r = c.post(f"/sessions/{session}/text", json={"text": text, "t": t})
        assert r.status_code == 201, r.text
        ids[text] = r.json()["ids"][0]
    return ids


def _touch_sense(dim: int) -> tuple[Any, str]:
    """The shipped TactusEncoder. No fallback: the browser tests promise the real touch
    sense, so a checkpoint that fails to load (or a space mismatch) fails them loudly."""
    from tactus_memory.adapters.touch import TactusEncoder

    enc = TactusEncoder()
    if int(enc.dim) != dim:
        raise RuntimeError(f"TactusEncoder dim {enc.dim} != space dim {dim}")
    return enc, "TactusEncoder (shipped checkpoint)"


def serve(data: str, port: int, token: str | None) -> None:
    import uvicorn

    from tactus_memory.memory.main import Memory
    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings
    from tactus_memory.spaces.minilm import MiniLMSpace

    memory = Memory.open(data, space=MiniLMSpace())
    sense, which = _touch_sense(memory.space.dim)
    memory.add_sense(sense)
    (Path(data).parent / "touch.json").write_text(json.dumps({"touch": which}))
    settings = Settings(data=data, host="127.0.0.1", port=port, token=token)
    uvicorn.run(
        create_app(settings, memory=memory), host="127.0.0.1", port=port, log_level="warning"
    )


# ----------------------------------------------------------------------------- touch data
def stag_windows(stag_dir: Path, n: int, k: int = 8) -> list[tuple[np.ndarray, str]]:
    """``n`` windows of ``k`` consecutive raw frames from a real STAG file (``weights_lite``
    when present), each from a different object, the firmest grasp of each (the mean of the
    30 strongest taxels): [(window int16, object name)]."""
    from tactus_memory.touch.profile import calibrate
    from tactus_memory.training.data import load_stag

    subs = sorted(p for p in stag_dir.iterdir() if (p / "metadata.mat").exists())
    sub = next((p for p in subs if p.name.startswith("weights")), subs[0] if subs else None)
    if sub is None:
        pytest.fail(f"no STAG metadata.mat under {stag_dir}")
    d = load_stag(sub / "metadata.mat")
    flat = calibrate(d.pressure).reshape(d.n_frames, -1)
    pressure = np.sort(flat, axis=1)[:, -30:].mean(axis=1)
    out: list[tuple[np.ndarray, str]] = []
    for obj in np.unique(d.object_id):
        name = d.objects[int(obj)]
        if name == "empty_hand":
            continue
        idx = np.flatnonzero(d.object_id == obj)
        idx = idx[idx + k <= d.n_frames]
        idx = idx[[np.all(d.object_id[i : i + k] == obj) for i in idx]]
        if idx.size == 0:
            continue
        best = int(idx[np.argmax(pressure[idx])])
        out.append((d.pressure[best : best + k].copy(), name))
        if len(out) == n:
            break
    if len(out) < n:
        pytest.fail(f"only {len(out)} objects with {k}-frame windows in {sub}")
    return out


def synthetic_windows(n: int, k: int = 8) -> list[tuple[np.ndarray, str]]:
    """``n`` STAG-format raw windows (``tests/stag_synth``: rest 511-516 on the taxels, sparse
    pressure up to raw 700) named after the first ``n`` objects that are not the empty hand:
    the stand-in for :func:`stag_windows` on a machine without the real files."""
    from tests.helpers.stag_synth import OBJECTS, make_pressure

    pressure = make_pressure([k] * n, np.random.default_rng(7), peak=700, n_poses=3)
    return [(pressure[i * k : (i + 1) * k], OBJECTS[1 + i]) for i in range(n)]


def npy_bytes(arr: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m tests.helpers.browser")
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="uvicorn + MiniLM + a touch sense on a store")
    s.add_argument("--data", required=True)
    s.add_argument("--port", type=int, required=True)
    s.add_argument("--token", default=None)
    args = ap.parse_args()
    serve(args.data, args.port, args.token)


if __name__ == "__main__":
    main()


def shot(page, tmp_path: Path, name: str) -> Path:
    path = tmp_path / f"{name}.png"
    page.screenshot(path=str(path), full_page=False)
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    shutil.copy(path, SCREENSHOTS / path.name)
    return path


SCREENSHOTS = ROOT / "runs" / "screenshots"


TIMEOUT_MS = 60_000


def png_size(data: bytes) -> tuple[int, int, str]:
    from PIL import Image

    with Image.open(io.BytesIO(data)) as img:
        return img.width, img.height, img.mode


def wait_heatmaps_loaded(page, selector: str) -> None:
    """The first image matching ``selector`` has loaded (images load lazily, on screen)."""
    page.locator(selector).first.scroll_into_view_if_needed()
    page.wait_for_function(
        """sel => { const i = document.querySelector(sel);
                    return i !== null && i.complete && i.naturalWidth > 0; }""",
        arg=selector,
    )


def first_hit(page) -> dict:
    return page.eval_on_selector(
        "#results > li.hit",
        """li => ({id: li.dataset.id, sense: li.dataset.sense,
                  text: li.querySelector('.hit-text')?.textContent ?? null})""",
    )
