"""Startup checks for ``tactus serve``: every mistake is ONE line that says what is wrong and
what to do (the command exits with status 2; ``--debug`` shows the traceback instead).

:func:`check_location` runs before the store is opened (local paths only): a ``--data`` that
is a regular file, or a new/empty directory this process cannot write; :func:`check_checkpoint`
refuses a ``--touch-checkpoint`` that is not a file. :func:`explain`
turns what opening the memory raised (a damaged manifest or table, a space mismatch, a bad
setting) into that one line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from tactus_memory.errors import InvalidInputError, TactusError
from tactus_memory.service.readiness import is_store_failure, short
from tactus_memory.storage.connect import is_remote_uri, normalise_uri


class StartupError(Exception):
    """A configuration or store problem found at startup; ``str()`` is the one line."""


def check_space_options(space_path: str | None, onnx: str | None) -> None:
    """What the space and model options can be checked for before anything loads (``tactus
    serve --workers N`` checks it once, before the workers start, so a mistake is one line,
    not one per worker): a ``--space-path`` that is not a folder, an ``--onnx`` folder that is
    a file. (Nothing here imports numpy or a model: the workers are forked after it.)"""
    if space_path is not None and not Path(space_path).expanduser().is_dir():
        raise StartupError(
            f"--space-path {space_path!r} is not a folder; pass --space-path DIR (or set "
            "TACTUS_SPACE_PATH) with a local model folder"
        )
    if onnx is not None and Path(onnx).exists() and not Path(onnx).is_dir():
        raise StartupError(f"--onnx {onnx!r} is a file; give the folder `tactus export-onnx` wrote")


def check_location(data: str) -> None:
    """Refuse a local ``--data`` that cannot be a memory directory (before opening it)."""
    if is_remote_uri(data):
        return  # object storage: the open itself reports
    try:
        path = Path(normalise_uri(data))
    except InvalidInputError:
        return  # an unknown scheme: opening the memory says which
    if path.exists() and not path.is_dir():
        raise StartupError(
            f"--data {data} is a regular file, not a memory directory: pass a directory "
            "(it is created when missing)"
        )
    if path.is_dir():
        if not os.access(path, os.R_OK | os.X_OK):
            raise StartupError(
                f"--data {data} cannot be read by this user: fix its permissions "
                f"(e.g. chmod u+rx {data}) or run as its owner"
            )
        empty = not any(path.iterdir())
        if empty and not os.access(path, os.W_OK):
            raise StartupError(
                f"--data {data} is an empty directory this user cannot write, so no memory "
                f"can be created there: fix its permissions (chmod u+w {data}) or choose "
                "another directory"
            )
        return
    parent = next((p for p in path.absolute().parents if p.exists()), None)
    if parent is not None and not os.access(parent, os.W_OK | os.X_OK):
        raise StartupError(
            f"--data {data} does not exist and cannot be created ({parent} is not writable): "
            "create it, fix the permissions, or choose another directory"
        )


def check_checkpoint(checkpoint: str | None) -> None:
    """Refuse a named touch checkpoint that is not a file, before the socket opens (the
    encoder itself loads behind the open socket; a file that then fails to load still stops
    the command with exit status 2)."""
    if checkpoint and not Path(checkpoint).is_file():
        raise StartupError(
            f"--touch-checkpoint {checkpoint} is not a file: pass a checkpoint written by "
            "`tactus train` (in this memory's space), or leave it out for the shipped one"
        )


def check_touch_senses(touch_senses: dict[str, str]) -> None:
    """Refuse a ``--touch NAME=CKPT`` whose checkpoint is not a file, before the socket opens."""
    for name, checkpoint in touch_senses.items():
        if not Path(checkpoint).is_file():
            raise StartupError(
                f"--touch {name}={checkpoint}: the checkpoint is not a file: pass one written "
                "by `tactus train` for that sensor (in this memory's space)"
            )


def parse_touch_senses(pairs: list[str]) -> dict[str, str]:
    """``--touch NAME=CKPT`` flags -> {name: checkpoint}; a malformed or repeated one is a
    :class:`StartupError` naming it."""
    out: dict[str, str] = {}
    for pair in pairs:
        name, sep, checkpoint = pair.partition("=")
        if not sep or not name.strip() or not checkpoint.strip():
            raise StartupError(
                f"--touch {pair}: expected NAME=CHECKPOINT, e.g. --touch skin=skin16.safetensors"
            )
        if name.strip() in out:
            raise StartupError(f"--touch {pair}: the sense {name.strip()!r} is named twice")
        out[name.strip()] = checkpoint.strip()
    return out


def explain(exc: BaseException, data: str) -> str:
    """One line for an exception raised while opening the memory or building the app."""
    if isinstance(exc, StartupError):
        return str(exc)
    if isinstance(exc, ValidationError):
        parts = [
            f"{'.'.join(str(p) for p in err['loc']) or 'setting'}: {err['msg']}"
            for err in exc.errors()
        ]
        return "invalid setting: " + "; ".join(parts)
    if isinstance(exc, TactusError):
        return f"cannot open the memory at {data}: {exc}"
    if is_store_failure(exc):
        return (
            f"the memory at {data} is damaged or unreadable ({short(exc, 200)}): restore it "
            "from a backup, or point --data at another directory"
        )
    return f"could not start ({type(exc).__name__}: {short(exc, 200)}); rerun with --debug"


def recorded_checkpoint(memory: Any, sense: str) -> tuple[str, str] | None:
    """(file name, sha256) of the checkpoint the store records for touch sense ``sense`` (the
    one its stored vectors were embedded by), or None when it records none."""
    prov = memory.registry.stored_provenance(sense) or {}
    sha = prov.get("checkpoint_sha256")
    return None if not sha else (str(prov.get("checkpoint", "?")), str(sha))


def check_named_checkpoint(memory: Any, sense: str, checkpoint: str | Path) -> None:
    """A checkpoint named for ``sense`` (``--touch-checkpoint``, ``--touch NAME=CKPT``) must be
    the one the store records: a store never holds two encoders' vectors for one sense
    (issue 48: a server restarted with the shipped checkpoint after ``tactus reembed`` wrote
    its vectors beside the re-embedded ones). Raises StartupError naming both."""
    from tactus_memory.hashing import file_sha256

    recorded = recorded_checkpoint(memory, sense)
    if recorded is None:
        return
    name, sha = recorded
    given = file_sha256(checkpoint)
    if given != sha:
        raise StartupError(
            f"the store's {sense!r} vectors were embedded by checkpoint {name} (sha256 "
            f"{sha[:12]}), but {Path(checkpoint).name} (sha256 {given[:12]}) was named for it: "
            "serve it without naming a checkpoint (the store's own is used), or move the "
            f"store to the new one with `tactus reembed --sense {sense} --checkpoint "
            f"{Path(checkpoint).name}`"
        )
