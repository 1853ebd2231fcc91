"""The sense contract: how one kind of raw input becomes a vector in the memory's space.

Shape of the plug-in (after LanceDB's embedding registry): a name, a modality, ``dim``,
``embed`` for stored items (source side), ``query_transform`` for text queries compared
against this sense (query side), input validation, provenance, and lazy model loading.
The memory never branches on a sense's name; everything sense-specific lives in the sense.

The implementations live in ``tactus_memory.adapters``, one file each (text, image, vectors,
touch). Every sense class registers under a name (``@register("text")``,
:mod:`tactus_memory.registry`); ``config()`` is what a store records to rebuild it with
``create(space, **config)``.
"""

from __future__ import annotations
