"""One resolver from "what the user named" to a :class:`Space`: name, model folder, dim.

Every entry point that opens a memory or trains into a space goes through
:func:`resolve_space` (the CLI's ``--space/--space-path/--space-dim``, the service settings,
``Memory.open``). Precedence, per field: the explicit argument, then the environment
(``TACTUS_SPACE``, ``TACTUS_SPACE_PATH``, ``TACTUS_SPACE_DIM``), then what the store
records, then the default (MiniLM). A store records the space's name, dim and model
fingerprint (:mod:`tactus_memory.spaces.fingerprint`), never the folder, so a folder that is
missing, not given, or holds another model is a one-line :class:`SpaceConfigError` naming the
option to pass.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from tactus_memory import spaces as registry
from tactus_memory.errors import SpaceConfigError
from tactus_memory.senses.plugins import lookup
from tactus_memory.settings import Settings
from tactus_memory.spaces.base import Space

ENV_SPACE_PATH = "TACTUS_SPACE_PATH"
PATH_HINT = f"pass --space-path DIR (or set {ENV_SPACE_PATH}; in Python space_path=DIR)"


@dataclass(frozen=True)
class SpaceChoice:
    """What the user named: any field may be None (then environment, store, default)."""

    name: str | None = None
    path: str | None = None
    dim: int | None = None

    def with_env(self) -> SpaceChoice:
        """Fill the fields not given from the settings (``TACTUS_SPACE``/``_PATH``/``_DIM``,
        or the settings file)."""
        try:
            env = Settings()
        except ValidationError as exc:
            err = exc.errors()[0]
            name = "TACTUS_" + "_".join(str(p) for p in err["loc"]).upper()
            raise SpaceConfigError(f"{name}={err['input']!r}: {err['msg']}") from None
        return SpaceChoice(
            name=self.name or env.space or None,
            path=self.path or env.space_path or None,
            dim=self.dim if self.dim is not None else env.space_dim,
        )


def recorded_space(raw: str | None) -> dict[str, Any] | None:
    """The store's ``space`` meta value (JSON) as a dict, or None for a fresh store."""
    return json.loads(raw) if raw else None


def _base_name(name: str) -> str:
    return name.strip().lower().partition("@")[0]


def needs_path(name: str) -> bool:
    """Whether the space registered as ``name`` needs a model folder (False: unknown name)."""
    try:
        return bool(lookup("space", _base_name(name)).needs_path)
    except ValueError:
        return False


def resolve_space(
    choice: SpaceChoice | None = None,
    recorded: dict[str, Any] | None = None,
    *,
    use_env: bool = True,
    owner: str = "this memory",
) -> Space:
    """Build the space the user named, checked against what a store ``recorded``.

    recorded: ``{"name", "dim", "fingerprint"?}`` from the store, or None (fresh store or no
    store: training; a checkpoint's ``space`` meta works too, with ``owner`` naming it in
    messages). Raises :class:`SpaceConfigError` (one line) when the folder is missing,
    not given, or holds another model than the recorded fingerprint.
    """
    choice = choice or SpaceChoice()
    if use_env:
        choice = choice.with_env()
    name = choice.name or (recorded or {}).get("name") or "minilm"
    dim = choice.dim
    same_base = recorded and _base_name(name) == _base_name(str(recorded["name"]))
    if dim is None and same_base and needs_path(name) and recorded is not None:
        dim = int(recorded["dim"])  # the store's Matryoshka dim, e.g. "...@512"
    where = f"{owner}'s space {recorded['name']!r} (dim {recorded['dim']})" if recorded else ""
    if recorded and not same_base:  # say so before asking for a folder it would not use
        raise SpaceConfigError(
            f"{owner} was created in space {recorded['name']!r} (dim {recorded['dim']}), "
            f"not {name!r}; pass --space {recorded['name']!r} or leave --space out"
        )
    if needs_path(name) and choice.path is None:
        what = where or f"space {name!r}"
        raise SpaceConfigError(
            f"{what} needs its local Qwen3-VL-Embedding-2B model folder: {PATH_HINT}"
        )
    if choice.path is not None and not Path(choice.path).expanduser().is_dir():
        raise SpaceConfigError(
            f"--space-path {choice.path!r} is not a folder; {PATH_HINT} with a local model folder"
        )
    try:
        # looked up on the module at call time (tests swap the registry function)
        given: dict[str, Any] = {"path": choice.path, "dim": dim}
        space = registry.get_space(name, **{k: v for k, v in given.items() if v is not None})
    except SpaceConfigError:
        raise
    except FileNotFoundError as exc:
        raise SpaceConfigError(f"{exc} ({PATH_HINT})") from None
    except ValueError as exc:  # InvalidInputError included: e.g. a dim the model cannot give
        if recorded and choice.path is not None:
            raise SpaceConfigError(
                f"--space-path {choice.path!r} cannot give {where}: {exc}; {PATH_HINT} naming "
                f"the folder {owner} was created with"
            ) from None
        raise SpaceConfigError(str(exc)) from None
    if recorded:
        check_recorded(space, recorded, path=choice.path, owner=owner)
    return space


def check_recorded(
    space: Space,
    recorded: dict[str, Any],
    *,
    path: str | None = None,
    owner: str = "this memory",
) -> None:
    """Raise SpaceConfigError when ``space`` is not the one the store (or checkpoint)
    recorded: name and dim, then the model fingerprint when both have one."""
    if space.name != recorded["name"] or int(space.dim) != int(recorded["dim"]):
        raise SpaceConfigError(
            f"{owner} was created in space {recorded['name']!r} (dim {recorded['dim']}), "
            f"not {space.name!r} (dim {space.dim}); pass --space {recorded['name']!r}"
        )
    want = recorded.get("fingerprint")
    have = space.fingerprint()
    if want and have and want != have:
        where = f"--space-path {path!r}" if path else "the given model folder"
        raise SpaceConfigError(
            f"{where} holds another model (fingerprint {have}) than {owner} was created "
            f"with (fingerprint {want}); {PATH_HINT} naming the folder it was created with"
        )
