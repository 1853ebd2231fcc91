"""Get the public STAG "lite" files into the data folder: download (resumable, sha256-checked)
or import files the user already has.

The ONE place that says where the files come from is :class:`StagSource`: a base URL (default:
the public mirror of the lite files in the ``sri-sensors/ini_estim`` GitHub repository, pinned
to one commit so the bytes cannot change under the pins) and the sha256 pins of the subsets.
Both can be overridden: ``TACTUS_STAG_BASE_URL`` (or ``--base-url``) and ``TACTUS_STAG_SHA256``
(``name=sha,name=sha``), e.g. for an institutional mirror.

A file lands as ``<data>/stag/<subset>/metadata.mat`` only after its sha256 matched; until
then it is ``metadata.mat.part``. An interrupted download keeps its ``.part`` and the next run
resumes it with an HTTP ``Range`` request; a wrong sha256 deletes the ``.part`` and raises
:class:`ChecksumError`. Every file placed is recorded in ``<data>/stag/SHA256SUMS``
(``sha256sum -c`` format).

Import (``--from DIR``): every ``<subset>/metadata.mat`` under DIR (DIR may be the data folder,
its ``stag`` folder or one subset folder). A subset with a pin must match it (a mismatch is an
error, nothing is copied); other subsets (e.g. a local re-save such as
``blindfolded_lite_train``) are imported with their sha256 recorded and a warning that they
could not be verified.
"""

from __future__ import annotations

import http.client
import os
import shutil
import sys
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from tactus_memory.datasets.home import ENV_DATA, STAG, user_data_dir
from tactus_memory.errors import TactusError
from tactus_memory.hashing import file_sha256

#: the public mirror of the STAG lite files (the dataset itself: http://stag.csail.mit.edu),
#: pinned to the commit the sums below were taken from
MIRROR_COMMIT = "c534875a60219b11303e4323c4b79ac1be84b964"
DEFAULT_BASE_URL = (
    f"https://raw.githubusercontent.com/sri-sensors/ini_estim/{MIRROR_COMMIT}/ini_estim/data/stag"
)
#: sha256 of ``<subset>/metadata.mat`` as published (the lite subsets: pressure only, no video)
PINNED_SHA256: dict[str, str] = {
    "weights_lite": "83d04f5f065435487532e392ef65c1f28ebf245f00f20983d8c6c8c65984fcf1",
    "blindfolded_lite": "00abb7967dceb2ce75ff813d502b5f170f76d8a588ad36ee0e61efb131130ba5",
}
ENV_BASE_URL = "TACTUS_STAG_BASE_URL"
ENV_SHA256 = "TACTUS_STAG_SHA256"
FILE = "metadata.mat"
SUMS = "SHA256SUMS"
CHUNK = 1 << 16
TIMEOUT_S = 60.0

LICENCE = (
    "STAG data licence: the STAG tactile glove dataset (Sundaram et al., Nature 2019, "
    "http://stag.csail.mit.edu) is provided by its authors for NON-COMMERCIAL RESEARCH USE "
    "ONLY and is not for redistribution. By fetching it you accept those terms; do not "
    "commit the files, or anything cut from them, to a repository. Models trained on it "
    "inherit the terms (the shipped touch weights are CC-BY-NC-4.0)."
)


class FetchError(TactusError, RuntimeError):
    """A download or import that could not complete (network, HTTP status, interrupted)."""


class ChecksumError(FetchError, ValueError):
    """A file whose sha256 differs from its pin (nothing is left in place as if good)."""


@dataclass(frozen=True)
class StagSource:
    """Where the STAG lite files come from and what their bytes must hash to."""

    base_url: str = DEFAULT_BASE_URL
    pins: dict[str, str] = field(default_factory=lambda: dict(PINNED_SHA256))

    @classmethod
    def from_env(cls, base_url: str | None = None) -> StagSource:
        """Defaults, overridden by ``TACTUS_STAG_BASE_URL`` / ``TACTUS_STAG_SHA256`` and then
        by an explicit ``base_url``."""
        pins = dict(PINNED_SHA256)
        pins.update(parse_pins(os.environ.get(ENV_SHA256, "")))
        url = base_url or os.environ.get(ENV_BASE_URL, "").strip() or DEFAULT_BASE_URL
        return cls(base_url=url, pins=pins)

    @property
    def subsets(self) -> list[str]:
        return list(self.pins)

    def url(self, subset: str) -> str:
        return f"{self.base_url.rstrip('/')}/{subset}/{FILE}"


def parse_pins(text: str) -> dict[str, str]:
    """``"a=<sha256>,b=<sha256>"`` -> {"a": ..., "b": ...}; raises on a malformed entry."""
    pins: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, digest = part.partition("=")
        digest = digest.strip().lower()
        if not sep or not name.strip() or len(digest) != 64 or not _is_hex(digest):
            raise FetchError(f"{ENV_SHA256}: expected name=<64 hex digits>, got {part!r}")
        pins[name.strip()] = digest
    return pins


def _is_hex(s: str) -> bool:
    return all(c in "0123456789abcdef" for c in s)


def fetch_target() -> Path:
    """Where fetched files go: ``TACTUS_DATA_HOME`` when set, else the user's data folder (never
    the read-only ``../shared`` fallback that :func:`data_home` may resolve to)."""
    env = os.environ.get(ENV_DATA, "").strip()
    return Path(env).expanduser() if env else user_data_dir()


def looks_like_mat(path: Path) -> bool:
    """A MATLAB 5 MAT-file header, or HDF5 (v7.3, signature at 0 or after the 512-byte
    userblock): catches an HTML error page or a Git LFS pointer saved as ``metadata.mat``."""
    with path.open("rb") as f:
        head = f.read(520)
    hdf5 = b"\x89HDF\r\n\x1a\n"
    return head.startswith(b"MATLAB") or head[:8] == hdf5 or head[512:520] == hdf5


def record_sum(stag_root: Path, subset: str, digest: str) -> None:
    """Add or replace ``<digest>  <subset>/metadata.mat`` in ``stag/SHA256SUMS``."""
    sums = stag_root / SUMS
    name = f"{subset}/{FILE}"
    lines = sums.read_text().splitlines() if sums.exists() else []
    lines = [ln for ln in lines if ln.split("  ", 1)[-1] != name] + [f"{digest}  {name}"]
    tmp = sums.with_suffix(".tmp")
    tmp.write_text("\n".join(sorted(lines, key=lambda ln: ln.split("  ", 1)[-1])) + "\n")
    os.replace(tmp, sums)


def _finish(part: Path, dest: Path, expected: str | None, what: str) -> str:
    """Verify ``part`` (format, sha256) and move it to ``dest``; delete it when bad."""
    digest = file_sha256(part)
    if expected is not None and digest != expected:
        part.unlink(missing_ok=True)
        raise ChecksumError(
            f"{what}: sha256 {digest} does not match the pinned {expected}; "
            "nothing was kept (a wrong or changed source? see --base-url)"
        )
    if not looks_like_mat(part):
        part.unlink(missing_ok=True)
        raise FetchError(f"{what}: not a MATLAB MAT-file (an error page?); nothing was kept")
    os.replace(part, dest)
    return digest


def _progress(total: int | None, initial: int, desc: str, enabled: bool):  # noqa: ANN202
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit="B",
        unit_scale=True,
        unit_divisor=1024,
        desc=desc,
        disable=not enabled,
        file=sys.stderr,
    )


def download(
    url: str,
    dest: Path,
    *,
    sha256: str | None,
    progress: bool = True,
    timeout: float = TIMEOUT_S,
    desc: str | None = None,
) -> str:
    """Download ``url`` to ``dest`` through ``dest.part`` (resumed with ``Range`` when it
    exists), check its sha256, then move it in place. Returns the sha256. Folders are made
    only once the server answers, so a failed attempt leaves no empty folder behind."""
    part = dest.with_name(dest.name + ".part")
    offset = part.stat().st_size if part.exists() else 0
    headers = {"User-Agent": "tactus-memory (data fetch)"}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    try:
        resp = urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and offset:  # the .part already holds every byte
            return _finish(part, dest, sha256, url)
        raise FetchError(f"{url}: HTTP {exc.code} {exc.reason}") from exc
    except (urllib.error.URLError, OSError) as exc:
        raise FetchError(
            f"could not reach {url}: {getattr(exc, 'reason', exc)} "
            "(no network? `tactus data fetch stag --from DIR` imports files you have)"
        ) from exc
    with resp:
        dest.parent.mkdir(parents=True, exist_ok=True)
        if offset and resp.status == 206:
            got = resp.headers.get("Content-Range", "")
            if not got.startswith(f"bytes {offset}-"):
                raise FetchError(f"{url}: asked for bytes {offset}- but got {got!r}")
        elif offset:  # 200: the server ignored Range, start over
            offset = 0
        length = resp.headers.get("Content-Length")
        total = offset + int(length) if length is not None else None
        written = offset
        with (
            part.open("ab" if offset else "wb") as out,
            _progress(total, offset, desc or dest.parent.name, progress) as bar,
        ):
            try:
                for block in iter(lambda: resp.read(CHUNK), b""):
                    out.write(block)
                    written += len(block)
                    bar.update(len(block))
            except (http.client.HTTPException, OSError) as exc:
                raise FetchError(
                    f"{url}: download interrupted after {written} bytes ({exc!r}); "
                    "run the command again to resume"
                ) from exc
    if total is not None and written != total:
        raise FetchError(
            f"{url}: download interrupted after {written} of {total} bytes; "
            "run the command again to resume"
        )
    return _finish(part, dest, sha256, url)


@dataclass(frozen=True)
class Placed:
    """One subset file put in the data folder: ``status`` is ``downloaded``, ``imported``,
    ``present`` (already there and verified) or ``unverified`` (imported, no pin)."""

    subset: str
    path: Path
    sha256: str
    status: str


def fetch_stag(
    target: Path | None = None,
    *,
    source: StagSource | None = None,
    subsets: Iterable[str] | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
) -> list[Placed]:
    """Download the pinned STAG subsets into ``<target>/stag`` (default :func:`fetch_target`).

    Files already present with the right sha256 are kept; anything else is (re)downloaded."""
    source = source or StagSource.from_env()
    root = (target or fetch_target()) / STAG
    names = list(subsets) if subsets else source.subsets
    unknown = [n for n in names if n not in source.pins]
    if unknown:
        raise FetchError(f"no pinned sha256 for {unknown}; known: {source.subsets}")
    say(LICENCE)
    out: list[Placed] = []
    for name in names:
        dest = root / name / FILE
        pin = source.pins[name]
        if dest.exists() and file_sha256(dest) == pin:
            say(f"{name}: already present and verified ({dest})")
            out.append(Placed(name, dest, pin, "present"))
            continue
        say(f"{name}: {source.url(name)} -> {dest}")
        digest = download(source.url(name), dest, sha256=pin, progress=progress, desc=name)
        record_sum(root, name, digest)
        out.append(Placed(name, dest, digest, "downloaded"))
    return out


def find_subsets(folder: Path) -> dict[str, Path]:
    """``{subset: metadata.mat}`` under ``folder``: the data folder (``stag/<subset>/``), a
    ``stag`` folder (``<subset>/``) or one subset folder (``metadata.mat`` itself)."""
    folder = folder.expanduser()
    if (folder / FILE).is_file():
        return {folder.resolve().name: folder / FILE}
    for base in (folder / STAG, folder):
        found = {p.name: p / FILE for p in sorted(base.glob("*")) if (p / FILE).is_file()}
        if found:
            return found
    return {}


def import_stag(
    source_dir: Path,
    target: Path | None = None,
    *,
    source: StagSource | None = None,
    subsets: Iterable[str] | None = None,
    say: Callable[[str], None] = print,
) -> list[Placed]:
    """Copy STAG files the user already has into ``<target>/stag`` (see the module docstring
    for what is verified)."""
    source = source or StagSource.from_env()
    root = (target or fetch_target()) / STAG
    found = find_subsets(source_dir)
    if subsets:
        wanted = list(subsets)
        missing = [n for n in wanted if n not in found]
        if missing:
            raise FetchError(f"{source_dir}: no {missing} (found {sorted(found)})")
        found = {n: found[n] for n in wanted}
    if not found:
        raise FetchError(
            f"{source_dir}: no STAG files (expected <subset>/{FILE}, e.g. weights_lite/{FILE})"
        )
    say(LICENCE)
    out: list[Placed] = []
    for name, src in found.items():
        dest = root / name / FILE
        pin = source.pins.get(name)
        if dest.exists() and dest.resolve() == src.resolve():
            raise FetchError(f"{src} is already the data folder's file")
        if pin is not None and dest.exists() and file_sha256(dest) == pin:
            say(f"{name}: already present and verified ({dest})")
            out.append(Placed(name, dest, pin, "present"))
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        part = dest.with_name(dest.name + ".part")
        shutil.copyfile(src, part)
        digest = _finish(part, dest, pin, str(src))
        record_sum(root, name, digest)
        if pin is None:
            say(
                f"warning: {name}: no published sha256 to check it against; imported "
                f"unverified, sha256 {digest} recorded in {root / SUMS}"
            )
        else:
            say(f"{name}: verified and imported -> {dest}")
        out.append(Placed(name, dest, digest, "imported" if pin else "unverified"))
    return out
