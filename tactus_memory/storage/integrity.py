"""The store's integrity check: can every table's latest version be read back?

For each table (items, senses, meta): its latest manifest opens, every data file and deletion
file the manifest names is present and (data files) of the size it records (local stores;
object stores are checked by Lance alone), and Lance's own ``validate`` passes. A store that
fails is *damaged*: every write refuses it (:meth:`IntegrityWatch.require` raises
:class:`~tactus_memory.errors.StoreDamagedError`, the service's 503), ``/health`` and
``/ready`` answer 503 naming the damage, maintenance leaves it alone (a cleanup could remove
the older versions a repair needs), and ``tactus maintain --check`` reports it. Reads still
go on where they can.

The check stats a few files per fragment and reads no data: milliseconds for a store whose
fragments maintenance keeps few (``benchmarks/disk.py``). :class:`IntegrityWatch` re-runs it
at most every :data:`CHECK_EVERY_S` seconds on the write path.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

from tactus_memory.errors import StoreDamagedError
from tactus_memory.storage.connect import is_remote_uri

#: the write path re-checks the store at most this often (seconds); probes check every time
CHECK_EVERY_S = 2.0


@dataclass(frozen=True)
class Damage:
    """One problem of one table. ``detail`` names files by their name within the table,
    never by a filesystem path (it may reach an HTTP answer)."""

    table: str
    detail: str

    def __str__(self) -> str:
        return f"{self.table}: {self.detail}"


def _lance_message(exc: BaseException, uri: str) -> str:
    """One line of a Lance error, with the table's location and Rust source spots cut."""
    text = " ".join(str(exc).split()).split(", /rustc/")[0].split(", /home/")[0]
    for root in {uri, uri.lstrip("/"), os.path.realpath(uri), os.path.realpath(uri).lstrip("/")}:
        text = text.replace(root.rstrip("/") + "/", "")
    return text[:300]


def check_table(name: str, uri: str, storage_options: dict[str, str] | None = None) -> list[Damage]:
    """The damage of one Lance table at ``uri`` (empty: intact). A problem seen while the
    table moved on to a newer version (a compaction and cleanup removed the files of the
    version being checked) is checked again on the newer one, so it is not called damage."""
    import lance

    damage: list[Damage] = []
    for _ in range(3):
        version, damage = _check_once(name, uri, storage_options)
        if not damage:
            return damage
        try:
            latest = lance.dataset(uri, storage_options=storage_options or None).version
        except Exception:  # noqa: BLE001  (the manifest itself: the damage stands)
            return damage
        if latest == version:
            return damage
    return damage


def _check_once(
    name: str, uri: str, storage_options: dict[str, str] | None
) -> tuple[int | None, list[Damage]]:
    import lance

    try:
        ds = lance.dataset(uri, storage_options=storage_options or None)
    except Exception as exc:  # noqa: BLE001  (any failure to open is the answer)
        return None, [Damage(name, f"the manifest cannot be read: {_lance_message(exc, uri)}")]
    out: list[Damage] = []
    if not is_remote_uri(uri):
        for frag in ds.get_fragments():
            meta = frag.metadata
            for f in meta.files:
                path = os.path.join(uri, "data", f.path)
                want = f.file_size_bytes
                try:
                    size = os.path.getsize(path)
                except OSError:
                    out.append(Damage(name, f"data file {f.path} is missing"))
                    continue
                if want is not None and size != int(want):
                    out.append(
                        Damage(
                            name,
                            f"data file {f.path} is {size} bytes; the manifest records {int(want)}",
                        )
                    )
            deletion = meta.deletion_file
            if deletion is not None:
                rel = deletion.path(meta.id)
                if not os.path.exists(os.path.join(uri, rel)):
                    out.append(Damage(name, f"deletion file {os.path.basename(rel)} is missing"))
    if not out:
        try:
            ds.validate()
        except Exception as exc:  # noqa: BLE001  (Lance's own verdict)
            out.append(Damage(name, f"Lance validation failed: {_lance_message(exc, uri)}"))
    return int(ds.version), out


def check_store(
    tables: dict[str, str], storage_options: dict[str, str] | None = None
) -> list[Damage]:
    """The damage of every table (name -> uri) of a store (empty: intact)."""
    return [d for name, uri in tables.items() for d in check_table(name, uri, storage_options)]


class IntegrityWatch:
    """The last integrity verdict of a store, re-checked when older than ``max_age``."""

    def __init__(self, check: object) -> None:
        self._check = check  # () -> list[Damage]
        self._lock = threading.Lock()
        self._at = -float("inf")
        self._damage: list[Damage] = []

    def damage(self, max_age: float = CHECK_EVERY_S) -> list[Damage]:
        """The damage found by a check at most ``max_age`` seconds old (0: check now)."""
        with self._lock:
            if time.monotonic() - self._at >= max_age:
                self._damage = list(self._check())  # type: ignore[operator]
                self._at = time.monotonic()
            return self._damage

    def require(self) -> None:
        """Raise StoreDamagedError when the store is damaged (a check at most
        :data:`CHECK_EVERY_S` old): nothing is written into a store that cannot be read back."""
        damage = self.damage()
        if damage:
            raise StoreDamagedError(
                f"the store is damaged ({'; '.join(map(str, damage[:3]))}); writes are refused "
                "until it is repaired (`tactus maintain --check` lists the damage), reads go "
                "on where they can"
            )
