"""``memory.count`` IS ``memory.temporal.count``: a method of one of the memory's parts,
declared by name in the :class:`~tactus_memory.memory.main.Memory` class body.

```python
class Memory:
    count = Part("temporal", Temporal.count)   # memory.count(q, ...) -> memory.temporal.count
```

One implementation and one docstring (the part's); a type checker and an IDE see the part's
parameters and result (``Callable[P, R]`` from the method's own signature), and a reader of
the class sees every name it answers to.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar, overload

P = ParamSpec("P")
R = TypeVar("R")


class Part(Generic[P, R]):
    """A descriptor: on an instance, ``getattr(instance.<part>, <method name>)``. ``method``
    is the part's class's function (``Temporal.count``): its first parameter is the part."""

    def __init__(self, part: str, method: Callable[Concatenate[Any, P], R]) -> None:
        self.part = part
        self.name = method.__name__
        self.__doc__ = method.__doc__
        self.__wrapped__ = method

    def __set_name__(self, owner: type, name: str) -> None:
        if name != self.name:  # memory.<name> is memory.<part>.<name>, never renamed
            raise TypeError(f"{owner.__name__}.{name} names {self.part}.{self.name}")

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> Part[P, R]: ...
    @overload
    def __get__(self, obj: object, owner: type | None = None) -> Callable[P, R]: ...
    def __get__(self, obj: object | None, owner: type | None = None) -> Any:
        if obj is None:
            return self
        return getattr(getattr(obj, self.part), self.name)
