"""The registry of spaces and senses, after LanceDB's embedding-function registry: a class
registers under a name with ``@register("touch")``, and is created back from that name and a
config, which is what a store records for every sense it has seen.

```python
@register("audio")
class AudioSense(Sense):
    modality = "audio"

    def __init__(self, space: Space, name: str = "audio") -> None: ...
    def validate(self, item): ...  # one clip -> its canonical form
    def embed(self, batch): ...  # N clips -> (N, D) unit rows
```

A **space** class registers its names (``@register("minilm", "minilm-l6")``) and builds itself
from the user's options with ``create(path=..., dim=...)`` (:func:`tactus_memory.spaces.get_space`).
A **sense** class gives ``config()`` (its JSON keywords) and is rebuilt by
``create(space, **config)``; the sense registry of a memory records both when the sense is
added, so a reopened store rebuilds its live senses (``memory.restore_senses()``).

The built-in plug-ins register when their modules are imported; :data:`BUILTINS` names those
modules, imported on the first lookup of a name not registered yet.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, Literal, TypeVar

Kind = Literal["space", "sense"]
T = TypeVar("T", bound=type)

#: the modules that register the built-in plug-ins of each kind
BUILTINS: dict[str, tuple[str, ...]] = {
    "space": ("tactus_memory.spaces.minilm", "tactus_memory.spaces.qwen3vl"),
    "sense": (
        "tactus_memory.adapters.text",
        "tactus_memory.adapters.image",
        "tactus_memory.adapters.vectors",
        "tactus_memory.adapters.touch",
    ),
}
_TABLES: dict[str, dict[str, type]] = {"space": {}, "sense": {}}


def register(name: str, *aliases: str) -> Callable[[T], T]:
    """Class decorator: register a Space or Sense subclass under ``name`` (and ``aliases``,
    looked up case-insensitively). Its ``registered_as`` becomes ``name``."""

    def deco(cls: T) -> T:
        kind = getattr(cls, "plugin_kind", None)
        if kind not in _TABLES:
            raise TypeError(f"{cls.__name__} is neither a Space nor a Sense; cannot register it")
        table = _TABLES[kind]
        for key in (name, *aliases):
            key = key.strip().lower()
            have = table.get(key)
            if have is not None and have.__qualname__ != cls.__qualname__:
                raise ValueError(f"{kind} {key!r} is already registered by {have.__qualname__}")
            table[key] = cls
        cls.registered_as = name  # type: ignore[attr-defined]
        return cls

    return deco


def _load(kind: Kind) -> None:
    for module in BUILTINS[kind]:
        importlib.import_module(module)


def lookup(kind: Kind, name: str) -> Any:
    """The class registered as ``name``; ValueError naming the known ones if none is."""
    key = name.strip().lower() if isinstance(name, str) else name
    table = _TABLES[kind]
    if key not in table:
        _load(kind)
    if key not in table:
        raise ValueError(f"unknown {kind} {name!r}; known {kind}s: {', '.join(known(kind))}")
    return table[key]


def create_sense(name: str, space: Any, /, **config: Any) -> Any:
    """A new sense of the class registered as ``name``, in ``space``, with ``config``."""
    return lookup("sense", name).create(space, **config)


def known(kind: Kind) -> list[str]:
    """Every registered name (aliases included), sorted: the same list whatever order the
    modules registering them were imported in."""
    _load(kind)
    return sorted(_TABLES[kind])


def registered_name(obj: object) -> str | None:
    """The name ``type(obj)`` itself was registered under (None: not registered; a subclass
    of a registered class is not registered until it registers)."""
    return vars(type(obj)).get("registered_as")
