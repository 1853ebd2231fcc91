"""The paper's space end to end, on a tiny random Qwen3-VL saved as a real local folder.

Covers the space options (``--space qwen3vl --space-path DIR --space-dim N`` and the
``TACTUS_SPACE_*`` environment) on the library, the CLI and the service; the store's record
(name, dim, model fingerprint, never the folder); the one-line errors for a missing or other
model folder; images over HTTP (upload, limits, thumbnails, text->image and image->image
search); a touch encoder trained into that space and refused by a memory of another space;
and a served store reopened by a second real uvicorn server.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

from tactus_memory.adapters.image import THUMBNAIL_SIDE, ImageSense  # noqa: E402
from tactus_memory.errors import (  # noqa: E402
    SenseConflictError,
    SpaceConfigError,
    SpaceMismatchError,
)
from tactus_memory.memory.main import Memory  # noqa: E402
from tactus_memory.spaces.fingerprint import model_fingerprint  # noqa: E402
from tactus_memory.spaces.qwen3vl import Qwen3VLSpace  # noqa: E402
from tests.helpers.qwen_tiny import HIDDEN, build_tiny_qwen3vl, perturbed_copy, png_bytes  # noqa: E402  # noqa: E402

QWEN = "qwen3-vl-embedding-2b"
SPACE_ENV = ("TACTUS_SPACE", "TACTUS_SPACE_PATH", "TACTUS_SPACE_DIM")


@pytest.fixture(scope="session")
def tiny_qwen(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny random Qwen3-VL: config.json, safetensors, tokenizer, image processor."""
    return build_tiny_qwen3vl(tmp_path_factory.mktemp("tiny-qwen3vl-e2e"))


@pytest.fixture(scope="session")
def other_qwen(tiny_qwen: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same architecture with other weights: "another model" for the fingerprint."""
    return perturbed_copy(tiny_qwen, tmp_path_factory.mktemp("other") / "qwen")


@pytest.fixture(autouse=True)
def _no_space_env(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in SPACE_ENV:
        monkeypatch.delenv(name, raising=False)


def _image(seed: int, size: tuple[int, int] = (64, 96)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (*size, 3), dtype=np.uint8)


def _one_line(text: str) -> str:
    """The one error line (serve's "[i/n] ..." steps and model-loading bars may come before it;
    nothing else, and no traceback)."""
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    progress = re.compile(r"^\[\d+/\d+\] |it/s\]$")  # serve's steps, tqdm bars
    lines = [ln for ln in lines if not progress.search(ln)]
    assert len(lines) == 1, f"expected one line, got {len(lines)}:\n{text}"
    return lines[0]


# -- the store's record and the library ------------------------------------------------------


def test_fingerprint_names_the_model_not_the_folder(
    tiny_qwen: Path, other_qwen: Path, tmp_path: Path
) -> None:
    moved = Path(shutil.copytree(tiny_qwen, tmp_path / "moved"))
    assert model_fingerprint(moved) == model_fingerprint(tiny_qwen)
    assert model_fingerprint(other_qwen) != model_fingerprint(tiny_qwen)
    cfg = json.loads((moved / "config.json").read_text())
    cfg["text_config"]["rms_norm_eps"] = 1e-5
    (moved / "config.json").write_text(json.dumps(cfg))
    assert model_fingerprint(moved) != model_fingerprint(tiny_qwen)


def test_memory_records_space_and_reopens_from_option_or_env(
    tiny_qwen: Path, other_qwen: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = str(tmp_path / "mem")
    mem = Memory.open(data, space="qwen3vl", space_path=str(tiny_qwen), background=False)
    assert (mem.space.name, mem.space.dim, mem.space.has_vision) == (QWEN, HIDDEN, True)
    mem.add_sense(ImageSense(mem.space))
    picture = _image(0, (300, 200))
    img_id = mem.add("s1", "image", picture, t=1.0)
    text_id = mem.add("s1", "text", "holding a mug", t=2.0)
    record = json.loads(mem.store.get_meta("space"))
    assert record == {"name": QWEN, "dim": HIDDEN, "fingerprint": model_fingerprint(tiny_qwen)}
    stored = json.dumps([mem.store.get_meta("space"), mem.store.sense_rows()], default=str)
    assert str(tiny_qwen) not in stored  # the folder is never recorded, only the model
    mem.close()

    with pytest.raises(SpaceConfigError, match="--space-path") as missing:
        Memory.open(data, background=False)
    assert "\n" not in str(missing.value) and f"'{QWEN}' (dim {HIDDEN})" in str(missing.value)
    with pytest.raises(SpaceConfigError, match="another model") as other:
        Memory.open(data, space_path=str(other_qwen), background=False)
    assert "\n" not in str(other.value) and "--space-path" in str(other.value)
    with pytest.raises(SpaceConfigError, match="not a folder"):
        Memory.open(data, space_path=str(tmp_path / "nowhere"), background=False)
    with pytest.raises(SpaceMismatchError, match="fingerprinted"):  # a Space object: the store
        Memory.open(data, space=Qwen3VLSpace(other_qwen), background=False)

    monkeypatch.setenv("TACTUS_SPACE_PATH", str(tiny_qwen))
    again = Memory.open(data, background=False)  # the path from the environment
    again.add_sense(ImageSense(again.space))
    like = again.search_like("image", picture, k=2)
    assert like[0].id == img_id and like[0].cosine > 0.999  # image -> image
    from PIL import Image

    rgba = Image.fromarray(picture).convert("RGBA")  # e.g. a PNG with alpha, as opened
    assert again.search_like("image", rgba, k=1)[0].id == img_id
    to_image = again.search("a white mug on a table", k=5, senses=["image"])  # text -> image
    assert [h.id for h in to_image] == [img_id]
    assert {h.id for h in again.search("holding a mug", k=5)} == {img_id, text_id}
    thumb = again.get_item(img_id).raw
    assert thumb.dtype == np.uint8 and thumb.shape == (THUMBNAIL_SIDE, round(256 * 200 / 300), 3)
    again.close()


def test_matryoshka_dim_is_recorded_and_reused(tiny_qwen: Path, tmp_path: Path) -> None:
    data = str(tmp_path / "m64")
    mem = Memory.open(data, space="qwen3vl", space_path=str(tiny_qwen), space_dim=64)
    assert (mem.space.name, mem.space.dim) == (f"{QWEN}@64", 64)
    mem.add("s", "text", "a soft sponge", t=0.0)
    mem.close()
    again = Memory.open(data, space_path=str(tiny_qwen))  # the dim comes from the record
    assert (again.space.name, again.space.dim) == (f"{QWEN}@64", 64)
    assert again.search("a soft sponge", k=1)[0].text == "a soft sponge"
    again.close()
    with pytest.raises(SpaceConfigError, match="dim 64"):
        Memory.open(data, space="qwen3vl", space_path=str(tiny_qwen), space_dim=96)


def test_moments_carry_image_evidence(tiny_qwen: Path, tmp_path: Path) -> None:
    mem = Memory.open(str(tmp_path / "mom"), space="qwen3vl", space_path=str(tiny_qwen))
    mem.add_sense(ImageSense(mem.space))
    img_ids = [mem.add("s1", "image", _image(i), t=float(10 * i)) for i in range(4)]
    mem.add("s1", "text", "a mug on the shelf", t=0.5)
    moments = mem.search_moments("a mug on the shelf", k=10, threshold=-100.0, relative=0.0)
    image_evidence = {h.id for m in moments for h in m.hits if h.sense == "image"}
    assert image_evidence and image_evidence <= set(img_ids)
    mem.close()


# -- the CLI ----------------------------------------------------------------------------------


def _cli(args: list[str], env: dict[str, str] | None = None) -> Any:
    from typer.testing import CliRunner

    from tactus_memory.cli import app

    return CliRunner().invoke(app, args, env=env)


def test_cli_space_options_and_one_line_errors(
    tiny_qwen: Path, other_qwen: Path, tmp_path: Path
) -> None:
    data = str(tmp_path / "mem")
    mem = Memory.open(data, space="qwen3vl", space_path=str(tiny_qwen), background=False)
    note = mem.add("s1", "text", "put the mug on the shelf", t=1.0)
    mem.close()

    r = _cli(["search", "mug", "--data", data, "--json"])
    assert r.exit_code == 2
    assert "--space-path" in _one_line(r.stderr) and QWEN in r.stderr
    r = _cli(["search", "mug", "--data", data, "--json", "--space-path", str(other_qwen)])
    assert r.exit_code == 2 and "another model" in _one_line(r.stderr)
    r = _cli(["search", "mug", "--data", data, "--json", "--space-path", str(tiny_qwen)])
    assert r.exit_code == 0, r.output
    assert [h["id"] for h in json.loads(r.stdout)] == [note]
    r = _cli(["sessions", "--data", data, "--json"], env={"TACTUS_SPACE_PATH": str(tiny_qwen)})
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)[0]["id"] == "s1"
    r = _cli(["search", "mug", "--data", data, "--space", "minilm", "--json"])
    assert r.exit_code == 2 and QWEN in _one_line(r.stderr)

    # serve stops before listening, with one line, when the space cannot be built
    serve = ["serve", "--workers", "1"]  # one process: the error is the command's own
    r = _cli([*serve, "--data", data, "--no-touch"])
    assert r.exit_code == 2 and "--space-path" in _one_line(r.stderr)
    fresh = str(tmp_path / "fresh")
    r = _cli([*serve, "--data", fresh, "--space", "qwen3vl", "--no-touch"])
    assert r.exit_code == 2 and "TACTUS_SPACE_PATH" in _one_line(r.stderr)
    r = _cli([*serve, "--data", fresh, "--space", "qwen3vl", "--space-path", str(tmp_path / "x")])
    assert r.exit_code == 2 and "not a folder" in _one_line(r.stderr)
    r = _cli([*serve, "--data", data, "--space-path", str(other_qwen), "--no-touch"])
    assert r.exit_code == 2 and "another model" in _one_line(r.stderr)
    missing = str(tmp_path / "no-such.safetensors")
    r = _cli(
        [*serve, "--data", data, "--space-path", str(tiny_qwen), "--touch-checkpoint", missing]
    )
    assert r.exit_code == 2 and "no-such.safetensors" in _one_line(r.stderr)


# -- a touch encoder trained into the space -------------------------------------------------


@pytest.fixture(scope="module")
def qwen_ckpt(tiny_qwen: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``tactus train --space qwen3vl --space-path DIR`` for a few steps on synthetic STAG."""
    from tests.helpers.stag_synth import make_fields, write_subset

    root = tmp_path_factory.mktemp("train-qwen")
    folder = write_subset(root, "cls", make_fields("classification", [40, 30, 25, 20]))
    out = root / "touch-qwen.safetensors"
    args = ["train", "--data", str(folder), "--out", str(out), "--space", "qwen3vl"]
    args += ["--space-path", str(tiny_qwen), "--steps", "3", "--batch", "8", "--device", "cpu"]
    r = _cli([*args, "--threads", "1"])
    assert r.exit_code == 0, r.output
    return out


def test_train_targets_come_from_the_space(qwen_ckpt: Path, tiny_qwen: Path) -> None:
    from tactus_memory.touch.checkpoint import load_checkpoint
    from tactus_memory.touch.targets import build_targets

    ckpt = load_checkpoint(qwen_ckpt)
    assert ckpt.meta["space"] == {
        "name": QWEN,
        "dim": HIDDEN,
        "fingerprint": model_fingerprint(tiny_qwen),
    }
    assert ckpt.meta["steps"] == 3
    expected = build_targets(Qwen3VLSpace(tiny_qwen), ckpt.classes)
    np.testing.assert_allclose(ckpt.targets.raw, expected.raw, atol=1e-4)
    assert ckpt.targets.centred.shape == (len(ckpt.classes), HIDDEN)


def test_train_without_the_folder_is_one_line(tmp_path: Path) -> None:
    r = _cli(
        ["train", "--data", str(tmp_path), "--out", str(tmp_path / "x.st"), "--space", "qwen3vl"]
    )
    assert r.exit_code == 2 and "--space-path" in _one_line(r.stderr)


def test_encoder_refuses_a_memory_of_another_space(
    qwen_ckpt: Path, tiny_qwen: Path, other_qwen: Path, tmp_path: Path
) -> None:
    from tactus_memory.adapters.touch import TactusEncoder
    from tests.helpers.fakes import HashingSpace

    minilm_like = Memory.open(str(tmp_path / "a"), space=HashingSpace(name="minilm-l6", dim=384))
    with pytest.raises(SenseConflictError) as exc:
        minilm_like.add_sense(TactusEncoder(qwen_ckpt))
    msg = str(exc.value)
    assert QWEN in msg and f"dimension {HIDDEN}" in msg and "'minilm-l6' (dimension 384)" in msg
    minilm_like.close()

    other = Memory.open(str(tmp_path / "b"), space="qwen3vl", space_path=str(other_qwen))
    with pytest.raises(SenseConflictError, match="fingerprint"):
        other.add_sense(TactusEncoder(qwen_ckpt))
    other.close()

    mem = Memory.open(str(tmp_path / "c"), space="qwen3vl", space_path=str(tiny_qwen))
    mem.add_sense(TactusEncoder(qwen_ckpt))
    window = np.full((8, 32, 32), 560, np.int16)
    touch_id = mem.add("s1", "touch", window, t=1.0, t_end=2.0)
    assert mem.search_like("touch", window, k=1)[0].id == touch_id
    assert touch_id in {h.id for h in mem.search("holding a mug", k=5, senses=["touch"])}
    mem.close()


def test_eval_builds_the_checkpoints_space_from_the_option(
    qwen_ckpt: Path, tiny_qwen: Path, other_qwen: Path, tmp_path: Path
) -> None:
    from tests.helpers.stag_synth import make_fields, write_subset

    folder = write_subset(tmp_path, "cls", make_fields("classification", [40, 30, 25, 20]))
    base = ["eval", "--checkpoint", str(qwen_ckpt), "--data", str(folder), "--votes", "1"]
    out = tmp_path / "with.json"
    r = _cli([*base, "--json", str(out), "--space-path", str(tiny_qwen)])
    assert r.exit_code == 0, r.output
    notes = json.loads(out.read_text())["analysis"]["notes"]
    assert not any("text space unavailable" in n for n in notes)
    out2 = tmp_path / "without.json"
    r = _cli([*base, "--json", str(out2)])
    assert r.exit_code == 0, r.output
    notes = json.loads(out2.read_text())["analysis"]["notes"]
    assert any("text space unavailable" in n for n in notes)
    r = _cli([*base, "--json", str(out2), "--space-path", str(other_qwen)])
    assert r.exit_code == 2 and "another model" in _one_line(r.stderr)


# -- images over HTTP (in-process) -----------------------------------------------------------


@pytest.fixture(scope="module")
def client(tiny_qwen: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    from fastapi.testclient import TestClient

    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    data = tmp_path_factory.mktemp("served") / "memory"
    settings = Settings(
        data=str(data),
        space="qwen3vl",
        space_path=str(tiny_qwen),
        touch=False,
        max_body_bytes=256 * 1024,
    )
    with TestClient(create_app(settings)) as c:
        yield c


def _post_image(c: Any, data: bytes, name: str = "a.png", t: float = 1.0, **form: Any) -> Any:
    files = {"file": (name, io.BytesIO(data), "application/octet-stream")}
    return c.post("/sessions/cam/image", files=files, data={"t": str(t), **form})


def test_http_image_ingest_limits_and_thumbnails(client: Any) -> None:
    from PIL import Image

    r = _post_image(client, png_bytes(1, (300, 120)), meta=json.dumps({"cam": "left"}))
    assert r.status_code == 201, r.text
    png_id = r.json()["ids"][0]
    r = _post_image(client, png_bytes(2, fmt="JPEG"), "b.jpg", t=2.0)
    assert r.status_code == 201, r.text

    bad = {
        b"not an image at all": "not a readable",
        png_bytes(3, fmt="GIF"): "format GIF",
        png_bytes(4, (4, 64)): ">= 8 px",
        b"": "empty",
    }
    for body, why in bad.items():
        r = _post_image(client, body)
        assert r.status_code == 422 and why in r.json()["detail"], (why, r.text)
    big = png_bytes(5, (400, 400))  # ~480 KB of noise, over the 256 KiB body limit
    assert _post_image(client, big).status_code == 413

    r = client.get(f"/items/{png_id}/image.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    thumb = Image.open(io.BytesIO(r.content))
    assert thumb.size == (round(THUMBNAIL_SIDE * 120 / 300), THUMBNAIL_SIDE)  # (w, h)
    small = Image.open(io.BytesIO(client.get(f"/items/{png_id}/image.png?size=32").content))
    assert max(small.size) == 32
    note = client.post("/sessions/cam/text", json={"text": "a mug", "t": 3.0}).json()["ids"][0]
    assert client.get(f"/items/{note}/image.png").status_code == 422
    assert client.get("/items/nope/image.png").status_code == 404


def test_http_text_to_image_and_image_to_image(client: Any) -> None:
    picture = png_bytes(11, (96, 64))
    r = _post_image(client, picture, t=10.0)
    assert r.status_code == 201
    pid = r.json()["ids"][0]
    for seed in (12, 13):
        assert _post_image(client, png_bytes(seed), t=11.0).status_code == 201

    files = {"file": ("q.png", io.BytesIO(picture), "image/png")}
    r = client.post("/search/like/image", files=files, data={"k": "3"})
    assert r.status_code == 200, r.text
    hits = r.json()["hits"]
    assert hits[0]["id"] == pid and hits[0]["cosine"] > 0.999
    assert {h["sense"] for h in hits} == {"image"}

    r = client.get("/search", params={"q": "a photo of a mug", "sense": "image", "k": 50})
    assert r.status_code == 200
    ids = [h["id"] for h in r.json()["hits"]]
    assert pid in ids and {h["sense"] for h in r.json()["hits"]} == {"image"}

    files = {"file": ("q.png", io.BytesIO(b"garbage"), "image/png")}
    assert client.post("/search/like/image", files=files).status_code == 422


def test_http_image_routes_need_a_vision_space(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from tactus_memory.service.app import create_app
    from tests.helpers.service import make_memory

    with TestClient(create_app(memory=make_memory(tmp_path / "m", touch=False))) as c:
        files = {"file": ("q.png", io.BytesIO(png_bytes(0)), "image/png")}
        r = c.post("/search/like/image", files=files)
        assert r.status_code == 400 and "no vision" in r.json()["detail"]
        assert _post_image(c, png_bytes(0)).status_code == 400


# -- the real thing: two uvicorn servers on one store ----------------------------------------


@pytest.mark.slow
def test_served_store_is_reopened_by_a_second_server(
    tiny_qwen: Path, qwen_ckpt: Path, tmp_path: Path
) -> None:
    import httpx

    from tests.helpers.servers import Server

    data = tmp_path / "memory"
    space = ["--space-path", str(tiny_qwen), "--touch-checkpoint", str(qwen_ckpt)]
    first = Server(data, tmp_path / "one.log", "--space", "qwen3vl", *space)
    picture = png_bytes(21, (128, 96))
    try:
        with httpx.Client(base_url=first.base, timeout=120) as c:
            senses = {s["name"] for s in c.get("/senses").json()["senses"]}
            assert senses >= {"text", "image", "touch"}
            files = {"file": ("p.png", picture, "image/png")}
            r = c.post("/sessions/kitchen/image", files=files, data={"t": "1.0"})
            assert r.status_code == 201, r.text
            img_id = r.json()["ids"][0]
            frames = np.full((8, 32, 32), 560, np.int16).tolist()
            r = c.post("/sessions/kitchen/touch", json={"frames": frames, "t": 1.5, "t_end": 2.5})
            assert r.status_code == 201, r.text
            touch_id = r.json()["ids"][0]
            r = c.post("/sessions/kitchen/text", json={"text": "grasping a coffee mug", "t": 2.0})
            text_id = r.json()["ids"][0]
            hits = c.get("/search", params={"q": "grasping a coffee mug", "k": 10}).json()["hits"]
            assert {h["id"] for h in hits} == {img_id, touch_id, text_id}
    finally:
        first.stop()

    # the second server names only the folder: the store's record gives the space and dim
    second = Server(data, tmp_path / "two.log", *space)
    try:
        with httpx.Client(base_url=second.base, timeout=120) as c:
            hits = c.get("/search", params={"q": "grasping a coffee mug", "k": 10}).json()["hits"]
            assert {h["id"] for h in hits} == {img_id, touch_id, text_id}
            assert {h["sense"] for h in hits} == {"image", "touch", "text"}
            files = {"file": ("q.png", picture, "image/png")}
            like = c.post("/search/like/image", files=files).json()["hits"]
            assert like[0]["id"] == img_id
            png = c.get(f"/items/{img_id}/image.png")
            assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
            assert c.get(f"/items/{touch_id}/touch.png").status_code == 200
    finally:
        second.stop()

    # a third start without the folder stops at once with one line naming the option
    env = {k: v for k, v in os.environ.items() if k not in SPACE_ENV}
    cmd = [sys.executable, "-c", "from tactus_memory.cli import main; main()", "serve"]
    cmd += ["--workers", "1"]
    done = subprocess.run(
        [*cmd, "--data", str(data), "--port", "0", "--no-touch"],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert done.returncode == 2
    assert "--space-path" in _one_line(done.stderr)
