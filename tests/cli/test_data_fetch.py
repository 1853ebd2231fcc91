"""The data folder and ``tactus data fetch stag``, end to end against a real HTTP server on
127.0.0.1 (``http.server``, with ``Range`` support) serving real STAG-format files (synthetic,
from ``tests/stag_synth``); the pins are those files' sums, passed through the configurable
:class:`StagSource` / ``TACTUS_STAG_SHA256``.
"""

from __future__ import annotations

import hashlib
import http.server
import json
import re
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.datasets.home import ENV_DATA, data_home
from tactus_memory.datasets.stag import (
    ENV_BASE_URL,
    ENV_SHA256,
    PINNED_SHA256,
    SUMS,
    ChecksumError,
    FetchError,
    StagSource,
    fetch_stag,
    import_stag,
    parse_pins,
)
from tactus_memory.training.data import load_stag
from tests.helpers.stag_synth import make_fields, write_subset

SUBSETS = ("weights_lite", "blindfolded_lite")


# ----------------------------------------------------------------------------- the server
class FileServer:
    """Serves ``files`` ({url path: bytes}) over real HTTP with ``Range: bytes=N-`` support.

    ``drop_after[path] = n``: the next GET of ``path`` announces the full length, sends ``n``
    body bytes and closes the connection (an interrupted download). Every request's path and
    Range header is recorded in ``log``."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.drop_after: dict[str, int] = {}
        self.log: list[tuple[str, str | None]] = []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: object) -> None:  # quiet
                pass

            def do_GET(self) -> None:  # noqa: N802
                rng = self.headers.get("Range")
                outer.log.append((self.path, rng))
                body = outer.files.get(self.path)
                if body is None:
                    self.send_error(404)
                    return
                start = 0
                m = re.fullmatch(r"bytes=(\d+)-", rng or "")
                if m:
                    start = int(m.group(1))
                    if start >= len(body):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(body)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
                else:
                    self.send_response(200)
                chunk = body[start:]
                self.send_header("Content-Length", str(len(chunk)))
                self.send_header("Accept-Ranges", "bytes")
                self.send_header("Content-Type", "application/octet-stream")
                drop = outer.drop_after.pop(self.path, None)
                if drop is not None:
                    self.send_header("Connection", "close")
                    self.end_headers()
                    self.wfile.write(chunk[:drop])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.end_headers()
                self.wfile.write(chunk)

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/stag"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(scope="module")
def synth_files(tmp_path_factory) -> dict[str, bytes]:
    """Real STAG-format metadata.mat bytes for the two lite subsets (synthetic content)."""
    root = tmp_path_factory.mktemp("mirror")
    write_subset(root, "weights_lite", make_fields("weights", [60, 50, 40], seed=1))
    write_subset(root, "blindfolded_lite", make_fields("blindfolded", [30, 25], seed=2))
    return {name: (root / name / "metadata.mat").read_bytes() for name in SUBSETS}


@pytest.fixture
def server(synth_files) -> Iterator[FileServer]:
    srv = FileServer()
    for name, body in synth_files.items():
        srv.files[f"/stag/{name}/metadata.mat"] = body
    yield srv
    srv.close()


def pins_of(files: dict[str, bytes]) -> dict[str, str]:
    return {name: hashlib.sha256(body).hexdigest() for name, body in files.items()}


def quiet(_: str) -> None:
    pass


# ----------------------------------------------------------------------------- download
def test_fetch_downloads_verifies_and_records(tmp_path, server, synth_files):
    source = StagSource(base_url=server.url, pins=pins_of(synth_files))
    lines: list[str] = []
    placed = fetch_stag(tmp_path, source=source, progress=False, say=lines.append)
    assert [(p.subset, p.status) for p in placed] == [(n, "downloaded") for n in SUBSETS]
    assert "NON-COMMERCIAL" in lines[0]  # the licence comes before any download
    for name in SUBSETS:
        dest = tmp_path / "stag" / name / "metadata.mat"
        assert dest.read_bytes() == synth_files[name]
        assert not dest.with_name("metadata.mat.part").exists()
    sums = (tmp_path / "stag" / SUMS).read_text().splitlines()
    assert sums == [f"{pins_of(synth_files)[n]}  {n}/metadata.mat" for n in sorted(SUBSETS)]
    d = load_stag(tmp_path / "stag" / "weights_lite")  # the reader takes what was fetched
    assert d.n_frames == 150 and d.n_recordings == 3
    # a second run finds both files verified and asks the server for nothing
    n_requests = len(server.log)
    again = fetch_stag(tmp_path, source=source, progress=False, say=quiet)
    assert [p.status for p in again] == ["present", "present"]
    assert len(server.log) == n_requests


def test_interrupted_download_resumes_with_range(tmp_path, server, synth_files):
    name = "weights_lite"
    body = synth_files[name]
    server.drop_after[f"/stag/{name}/metadata.mat"] = 5000
    source = StagSource(base_url=server.url, pins=pins_of(synth_files))
    dest = tmp_path / "stag" / name / "metadata.mat"
    part = dest.with_name("metadata.mat.part")
    with pytest.raises(FetchError, match="interrupted after 5000 of"):
        fetch_stag(tmp_path, source=source, subsets=[name], progress=False, say=quiet)
    assert not dest.exists() and part.stat().st_size == 5000
    assert part.read_bytes() == body[:5000]
    placed = fetch_stag(tmp_path, source=source, subsets=[name], progress=False, say=quiet)
    assert placed[0].status == "downloaded" and dest.read_bytes() == body
    assert server.log[-1] == (f"/stag/{name}/metadata.mat", "bytes=5000-")  # resumed
    assert not part.exists()


def test_corrupted_download_is_refused_and_removed(tmp_path, server, synth_files):
    name = "blindfolded_lite"
    path = f"/stag/{name}/metadata.mat"
    good = synth_files[name]
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF
    server.files[path] = bytes(bad)
    source = StagSource(base_url=server.url, pins=pins_of(synth_files))
    dest = tmp_path / "stag" / name / "metadata.mat"
    with pytest.raises(ChecksumError, match="does not match the pinned") as exc:
        fetch_stag(tmp_path, source=source, subsets=[name], progress=False, say=quiet)
    assert pins_of({name: good})[name] in str(exc.value)
    assert not dest.exists() and not dest.with_name("metadata.mat.part").exists()
    assert not (tmp_path / "stag" / SUMS).exists()
    server.files[path] = good  # the mirror is fixed: the next run succeeds from scratch
    placed = fetch_stag(tmp_path, source=source, subsets=[name], progress=False, say=quiet)
    assert placed[0].status == "downloaded" and dest.read_bytes() == good
    assert server.log[-1] == (path, None)


def test_http_errors_and_bad_requests_are_clear(tmp_path, server, synth_files):
    source = StagSource(base_url=server.url + "/nowhere", pins=pins_of(synth_files))
    with pytest.raises(FetchError, match="HTTP 404"):
        fetch_stag(tmp_path, source=source, progress=False, say=quiet)
    assert not (tmp_path / "stag").exists()  # a failed fetch leaves no empty folder (issue 26)
    with pytest.raises(FetchError, match="no pinned sha256"):
        fetch_stag(tmp_path, source=source, subsets=["handposes_lite"], say=quiet)
    dead = StagSource(base_url="http://127.0.0.1:9/stag", pins=pins_of(synth_files))
    with pytest.raises(FetchError, match="could not reach"):
        fetch_stag(tmp_path, source=dead, subsets=["weights_lite"], progress=False, say=quiet)
    assert not (tmp_path / "stag").exists()
    # an HTML page in place of the file, with a pin that matches it, is still refused
    html = b"<html>rate limited</html>"
    server.files["/stag/weights_lite/metadata.mat"] = html
    fooled = StagSource(base_url=server.url, pins={"weights_lite": pins_of({"x": html})["x"]})
    with pytest.raises(FetchError, match="not a MATLAB MAT-file"):
        fetch_stag(tmp_path, source=fooled, progress=False, say=quiet)
    assert not (tmp_path / "stag" / "weights_lite" / "metadata.mat").exists()


def test_pins_and_base_url_come_from_one_place(monkeypatch):
    monkeypatch.delenv(ENV_BASE_URL, raising=False)
    monkeypatch.delenv(ENV_SHA256, raising=False)
    default = StagSource.from_env()
    assert default.pins == PINNED_SHA256 and default.subsets == list(SUBSETS)
    assert default.url("weights_lite").startswith("https://raw.githubusercontent.com/")
    assert default.url("weights_lite").endswith("/ini_estim/data/stag/weights_lite/metadata.mat")
    monkeypatch.setenv(ENV_BASE_URL, "http://mirror.example/stag/")
    monkeypatch.setenv(ENV_SHA256, "weights_lite=" + "a" * 64)
    src = StagSource.from_env()
    assert src.url("weights_lite") == "http://mirror.example/stag/weights_lite/metadata.mat"
    assert src.pins["weights_lite"] == "a" * 64
    assert src.pins["blindfolded_lite"] == PINNED_SHA256["blindfolded_lite"]
    assert StagSource.from_env("http://cli.example").base_url == "http://cli.example"
    for bad in ("weights_lite", "weights_lite=abc", "=" + "a" * 64, "x=" + "g" * 64):
        with pytest.raises(FetchError, match=ENV_SHA256):
            parse_pins(bad)


# ----------------------------------------------------------------------------- import
def test_import_from_the_shared_layout(tmp_path, synth_files):
    """``--from`` takes ``weights_lite/metadata.mat`` + ``blindfolded_lite_train/...``: the
    pinned name is verified, the unpinned one imported with its sum recorded and a warning."""
    src = tmp_path / "have" / "stag"
    (src / "weights_lite").mkdir(parents=True)
    (src / "weights_lite" / "metadata.mat").write_bytes(synth_files["weights_lite"])
    write_subset(src, "blindfolded_lite_train", make_fields("blindfolded", [20, 20], seed=3))
    target = tmp_path / "data"
    source = StagSource(base_url="http://unused.invalid", pins=pins_of(synth_files))
    lines: list[str] = []
    placed = import_stag(src.parent, target, source=source, say=lines.append)
    assert {p.subset: p.status for p in placed} == {
        "weights_lite": "imported",
        "blindfolded_lite_train": "unverified",
    }
    train = src / "blindfolded_lite_train" / "metadata.mat"
    train_sum = hashlib.sha256(train.read_bytes()).hexdigest()
    assert any(ln.startswith("warning: blindfolded_lite_train") and train_sum in ln for ln in lines)
    sums = (target / "stag" / SUMS).read_text()
    assert f"{train_sum}  blindfolded_lite_train/metadata.mat" in sums
    assert load_stag(target / "stag" / "blindfolded_lite_train").n_recordings == 2
    # one subset folder works as --from too; a pinned name with other bytes is refused
    other = tmp_path / "other"
    write_subset(other, "weights_lite", make_fields("weights", [10, 10], seed=9))
    fresh = tmp_path / "fresh"
    with pytest.raises(ChecksumError):
        import_stag(other / "weights_lite", fresh, source=source, say=quiet)
    assert not (fresh / "stag" / "weights_lite" / "metadata.mat").exists()
    assert not (fresh / "stag" / "weights_lite" / "metadata.mat.part").exists()
    with pytest.raises(FetchError, match="no STAG files"):
        import_stag(tmp_path / "empty-dir", fresh, source=source, say=quiet)


# ----------------------------------------------------------------------------- data folder
def test_data_home_resolution(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV_DATA, str(tmp_path / "explicit"))
    home = data_home()
    assert (home.path, home.source, home.stag_subsets()) == (tmp_path / "explicit", "env", [])
    monkeypatch.delenv(ENV_DATA)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    home = data_home()  # empty user folder: the checkout's ../shared if it has files
    assert home.source in ("user", "checkout")
    if home.source == "user":
        assert home.path == tmp_path / "xdg" / "tactus"
    write_subset(tmp_path / "xdg" / "tactus" / "stag", "weights_lite", make_fields("weights"))
    home = data_home()  # files in the user folder win over the fallback
    assert (home.path, home.source) == (tmp_path / "xdg" / "tactus", "user")
    assert home.stag_subsets() == ["weights_lite"]


def test_cli_fetch_then_path_then_inspect(tmp_path, server, synth_files, monkeypatch):
    """The commands a stranger types, over real HTTP: fetch, where is it, inspect it."""
    from tactus_memory.cli import app

    pins = pins_of(synth_files)
    monkeypatch.setenv(ENV_DATA, str(tmp_path / "data"))
    monkeypatch.setenv(ENV_BASE_URL, server.url)
    monkeypatch.setenv(ENV_SHA256, ",".join(f"{k}={v}" for k, v in pins.items()))
    runner = CliRunner()
    res = runner.invoke(app, ["data", "fetch", "stag", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "NON-COMMERCIAL RESEARCH USE ONLY" in res.stderr
    rows = [ln.split("\t") for ln in res.stdout.splitlines()]
    assert [(r[0], r[1], r[2]) for r in rows] == [(n, "downloaded", pins[n]) for n in SUBSETS]
    res = runner.invoke(app, ["data", "path", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["source"] == "env" and out["stag_subsets"] == sorted(SUBSETS)
    res = runner.invoke(app, ["data", "path", "--stag"])
    assert res.stdout.strip() == str(tmp_path / "data" / "stag") == out["stag"]
    res = runner.invoke(app, ["data", "inspect", str(Path(out["stag"]) / "weights_lite"), "--json"])
    assert res.exit_code == 0 and json.loads(res.stdout)["frames"] == 150
    # a corrupted mirror: exit 1 and a message naming the problem, nothing new in place
    bad = np.frombuffer(synth_files["weights_lite"], np.uint8).copy()
    bad[-10:] ^= 0x55
    server.files["/stag/weights_lite/metadata.mat"] = bad.tobytes()
    (tmp_path / "data" / "stag" / "weights_lite" / "metadata.mat").unlink()
    res = runner.invoke(app, ["data", "fetch", "stag", "--no-progress"])
    assert res.exit_code == 1 and "does not match the pinned" in res.stderr
    assert not (tmp_path / "data" / "stag" / "weights_lite" / "metadata.mat").exists()
    res = runner.invoke(app, ["data", "fetch", "mnist"])
    assert res.exit_code == 2 and "unknown data set" in res.stderr
