"""Which windowed sense a route writes to or draws: ``?sense=NAME`` on the touch routes
(default ``touch``, the glove), ``{sense}`` in the generic windowed routes' paths.

The service knows windowed senses through their contract only
(:mod:`tactus_memory.senses.windowed`: ``frame_shape``, ``window_stream``, ``validate``'s idle
rule, ``drawer``) and the plug-in registry (the class registered as ``touch`` states the frame
the JSON schema shows and draws a sense known only from the store); it imports no touch module.

A memory may hold several touch senses side by side, each a Tactus checkpoint with its own
sensor profile and so its own frame shape (H, W): the 32x32 STAG glove as ``touch``, a 16x16
skin as ``skin``, a robot hand's pads assembled into one frame as ``left-hand``. The write
routes (``POST /sessions/{id}/touch``, the WebSocket stream), search by example and the heat
maps resolve the sense here, once, and check every frame against *its* shape; a window of
another shape is a 422 naming both shapes, an unknown sense a 404 naming it and the touch
senses there are, a sense that is not touch (``text``) a 422.

Extra touch senses are registered at startup from ``Settings.touch_senses``
(``tactus serve --touch NAME=CKPT``, repeated; ``TACTUS_TOUCH_SENSES``), or persist from an
earlier registration in the store (``Memory.add_sense(TactusEncoder(ckpt, name=NAME))``).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Path, Query

from tactus_memory.errors import InvalidInputError, UnknownSenseError
from tactus_memory.limits import SENSE_NAME_PATTERN
from tactus_memory.senses.plugins import lookup
from tactus_memory.senses.windowed import WindowDrawer, WindowedSense
from tactus_memory.service.deps import MemoryDep, StateDep
from tactus_memory.service.problems import ServiceUnavailable

#: the sense a touch route writes to when the request names none (the shipped glove)
DEFAULT_TOUCH_SENSE = "touch"
SENSE_DOC = (
    "The touch sense to write to (default `touch`, the 32x32 glove); each touch sense reads "
    "frames of its own shape (`GET /senses`: `shape`)."
)


def touch_sense_names(memory: Any) -> list[str]:
    """The live touch senses of ``memory`` (windowed senses: a frame shape, a window)."""
    return sorted(n for n, s in memory.senses.items() if getattr(s, "windowed", False))


def resolve_touch_sense(memory: Any, name: str, why_default_missing: str | None = None) -> Any:
    """The live touch sense ``name``: 503 when the default glove sense is not loaded (saying
    why), 404 for another name no sense has, 422 for a sense that is not touch."""
    sense = memory.senses.get(name)
    if sense is None:
        if name == DEFAULT_TOUCH_SENSE:
            why = why_default_missing or "no sense named 'touch' is registered in this memory"
            raise ServiceUnavailable(f"touch is not available on this server: {why}")
        raise UnknownSenseError(
            f"no touch sense {name!r} in this memory; touch senses here: "
            f"{touch_sense_names(memory) or 'none'}"
        )
    if not isinstance(sense, WindowedSense):
        raise InvalidInputError(
            f"sense {name!r} is a {sense.modality} sense, not touch: touch windows go to "
            f"{touch_sense_names(memory) or 'no sense here'}"
        )
    return sense


def frame_shape(sense: WindowedSense) -> tuple[int, ...]:
    """The shape of one frame of the windowed ``sense`` (the contract's ``frame_shape``: (H,
    W) for a touch sense, its checkpoint's sensor profile's; (C,) for an IMU)."""
    return tuple(int(n) for n in sense.frame_shape)


def default_sense_class() -> type[WindowedSense]:
    """The class registered as the default touch sense (``touch``, ``TactusEncoder``)."""
    cls: type[WindowedSense] = lookup("sense", DEFAULT_TOUCH_SENSE)
    return cls


def drawer_of(memory: Any, name: str) -> WindowDrawer:
    """How the windows of sense ``name`` are drawn: a live windowed sense's own drawer; for a
    live sense that draws none, or a sense known from the store only, the default touch
    class's drawer from the sense's provenance (the glove's when it records no sensor)."""
    live = memory.senses.get(name)
    drawer = live.drawer() if isinstance(live, WindowedSense) else None
    if drawer is not None:
        return drawer
    if live is not None:
        provenance = live.provenance()
    else:
        info = next((i for i in memory.sense_info() if i.name == name), None)
        if info is None:
            raise UnknownSenseError(f"no sense {name!r} in this memory")
        provenance = info.provenance
    drawer = default_sense_class().drawer_from_provenance(provenance)
    if drawer is None:
        raise InvalidInputError(f"sense {name!r} draws no picture of its windows")
    return drawer


def touch_sense_dep(
    state: StateDep,
    memory: MemoryDep,
    sense: Annotated[
        str, Query(pattern=SENSE_NAME_PATTERN, max_length=64, description=SENSE_DOC)
    ] = DEFAULT_TOUCH_SENSE,
) -> Any:
    """The touch sense the request names in ``?sense=`` (HTTP routes and WebSockets alike)."""
    return resolve_touch_sense(memory, sense, state.touch_unavailable)


#: the resolved touch sense of a touch route (``?sense=NAME``, default ``touch``)
TouchSenseDep = Annotated[Any, Depends(touch_sense_dep)]


def windowed_sense_dep(
    state: StateDep,
    memory: MemoryDep,
    sense: Annotated[
        str,
        Path(
            pattern=SENSE_NAME_PATTERN,
            max_length=64,
            description="The windowed sense written to (`GET /senses`: its `shape`).",
        ),
    ],
) -> Any:
    """The windowed sense the generic routes' path names (``/senses/{sense}/...``)."""
    return resolve_touch_sense(memory, sense, state.touch_unavailable)


#: the resolved windowed sense of a generic windowed route (``{sense}`` in the path)
WindowedSenseDep = Annotated[Any, Depends(windowed_sense_dep)]
