"""Read ahead what ``tactus serve`` reads while it starts, for a start with a cold file cache
(a robot's first start after a boot).

A start reads ~1,600 files: the bytecode of ~1,300 modules, the shared libraries they map
(LanceDB's and Lance's Rust runtimes, Arrow, ONNX Runtime) and the ONNX models. On a cold
cache Python reads them one ``.pyc`` or page fault at a time, each a wait on the disk. Here a
small reader process, forked before the command imports anything heavy, asks the kernel for
every file of the list the last start recorded, in that start's order (``posix_fadvise`` with
``WILLNEED``: the reads are queued, the reader does not wait for them), so the disk works
ahead of the imports instead of behind them. The page cache is the machine's: what the
reader brings in, the server finds.

Each start records its list once it is ready (:func:`record`: the modules of
``sys.modules``, which is in import order, the files in /proc/self/maps placed before their
package's first module, then the ONNX folder's files) in the user's cache, one list per
interpreter. A first start has no list and reads nothing ahead; a file gone since (an
upgrade) is skipped. ``TACTUS_PREFETCH=0`` turns it off. It acts where the OS has
``posix_fadvise`` (Linux); elsewhere it does nothing. Standard library only: it runs first.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import sys
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path

from tactus_memory.export.user_cache import cache_root

#: ``TACTUS_PREFETCH=0``: no read-ahead (the A/B of ``benchmarks/rss.py --cold``)
ENV = "TACTUS_PREFETCH"
#: in the list's file name: bump when what a list holds changes
LIST_VERSION = 1


def enabled() -> bool:
    """Whether this process may read ahead (an OS with ``posix_fadvise``, not turned off)."""
    return hasattr(os, "posix_fadvise") and os.environ.get(ENV, "1") != "0"


def list_path() -> Path:
    """The recorded list of this interpreter (its prefix and version name the file)."""
    key = hashlib.sha256(f"{sys.prefix}\0{sys.version}".encode()).hexdigest()[:12]
    return cache_root() / "prefetch" / f"serve-v{LIST_VERSION}-{key}.txt"


def read_ahead(paths: Iterable[str]) -> int:
    """Ask the kernel to read each file into its cache, without waiting for the reads; a
    missing or unreadable file is skipped. A module's bytecode (``__pycache__/*.pyc``) has
    its source looked up first, as an import does (it compares the two): the source's inode
    comes into the cache, its text is not read. Returns how many files were asked for."""
    from importlib.util import source_from_cache

    asked = 0
    for path in paths:
        if path.endswith(".pyc"):
            with contextlib.suppress(ValueError, OSError):
                os.stat(source_from_cache(path))
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_WILLNEED)
            asked += 1
        except OSError:
            pass
        finally:
            os.close(fd)
    return asked


def start(argv: Sequence[str]) -> bool:
    """For ``tactus serve`` (``argv[1]``), with a recorded list: read it ahead in the
    background. True where a reader was started."""
    if len(argv) < 2 or argv[1] != "serve" or not enabled():
        return False
    try:
        paths = list_path().read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        return False  # a first start (or an unreadable list): nothing to read ahead
    return _in_background(paths)


def _in_background(paths: list[str]) -> bool:
    """``read_ahead(paths)`` in a grandchild process: forked twice, so this process neither
    waits for it nor has it to reap (the child leaves at once; init adopts the reader). Its
    own interpreter lock: a thread here takes this process's lock back after each of its
    ~4,500 system calls, waiting up to the 5 ms switch interval whenever the imports hold it
    (beside a busy main thread, 12 ms of work took 1.4 s; docs/operations/speed.md). Only
    from a process with one thread (forking beside threads is unsafe), where ``os.fork``
    exists."""
    if not hasattr(os, "fork") or threading.active_count() > 1:
        return False
    try:
        pid = os.fork()
    except OSError:
        return False
    if pid == 0:  # the child: fork the reader, then leave at once, whatever happens
        try:
            if os.fork() == 0:
                signal.signal(signal.SIGINT, signal.SIG_DFL)  # Ctrl+C: gone, no traceback
                for fd in (0, 1, 2):  # no hold on the command's output (a pipe's reader)
                    with contextlib.suppress(OSError):
                        os.close(fd)
                read_ahead(paths)
        finally:
            os._exit(0)
    os.waitpid(pid, 0)
    return True


def _module_files() -> list[str]:
    """The file each loaded module was read from (its ``.pyc`` where it has one, else its
    source or its shared library), in import order."""
    out: list[str] = []
    for module in sys.modules.copy().values():
        spec = getattr(module, "__spec__", None)
        for path in (getattr(spec, "cached", None), getattr(spec, "origin", None)):
            if isinstance(path, str) and os.path.isfile(path):
                out.append(path)
                break
    return out


def _mapped_files(maps: str) -> list[str]:
    """The files mapped into a process, from the text of its /proc/PID/maps, sorted (the
    addresses, and so the lines' order, change with every start)."""
    out: set[str] = set()
    for line in maps.splitlines():
        fields = line.split(maxsplit=5)
        if len(fields) == 6 and fields[5].startswith("/") and not fields[5].endswith("(deleted)"):
            out.add(fields[5])
    return sorted(out)


def start_files(
    modules: Sequence[str], mapped: Sequence[str], folders: Sequence[str | Path] = ()
) -> list[str]:
    """The list a start reads ahead: ``modules`` in order, each of the ``mapped`` files not
    among them placed before the first module under its folder (``pyarrow/libarrow.so``
    before ``pyarrow``'s first module; ``numpy.libs/`` counts as ``numpy/``), else after
    them, then the files of ``folders`` (the ONNX models); each file once."""
    order = list(dict.fromkeys(modules))
    seen = set(order)
    before: dict[int, list[str]] = {}
    after: list[str] = []
    for path in mapped:
        if path in seen:
            continue
        seen.add(path)
        folder = os.path.dirname(path).removesuffix(".libs") + os.sep
        at = next((i for i, m in enumerate(order) if m.startswith(folder)), None)
        if at is None:
            after.append(path)
        else:
            before.setdefault(at, []).append(path)
    out = [p for i, m in enumerate(order) for p in (*before.get(i, ()), m)] + after
    for folder in folders:
        for path in sorted(Path(folder).glob("*")):
            if path.is_file() and str(path) not in seen:
                seen.add(str(path))
                out.append(str(path))
    return out


def record(folders: Sequence[str | Path] = ()) -> bool:
    """Record what this (ready) process read while it started, for the next start; the list
    is replaced whole and only when it changed. False where nothing was written (off, an
    unchanged list, or the cache not writable)."""
    if not enabled():
        return False
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        maps = ""
    text = "\n".join(start_files(_module_files(), _mapped_files(maps), folders)) + "\n"
    path = list_path()
    try:
        if path.is_file() and path.read_text() == text:
            return False
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError:
        return False
    return True
