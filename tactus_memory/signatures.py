"""Parameter groups: parameters that several functions share, declared once.

Typer (the CLI) and the MCP SDK (the tools) both read a function's signature to build its flags
or its JSON schema. :func:`grouped` lets a function take one parameter that stands for a group,
declared by a builder (a dataclass or a function whose own parameters are the group's):

```python
@dataclass(frozen=True)
class Window:
    after: After = None     # Annotated aliases: typer.Option(...) or pydantic Field(...)
    before: Before = None

@grouped(window=Window)
def count(query: str, window: Window) -> None: ...
```

The signature the frameworks see has ``after`` and ``before`` in place of ``window``; a call
with them builds ``Window(after=..., before=...)`` and passes it as ``window``.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Collection, Iterable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def reject_unknown(given: Iterable[str], allowed: Collection[str]) -> None:
    """TypeError naming the keywords ``given`` that are not ``allowed``, as Python says of a
    misspelt keyword argument (for functions that take ``**kw: Unpack[SomeTypedDict]``)."""
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise TypeError(f"unexpected keyword argument(s): {', '.join(unknown)}")


def grouped(**builders: Callable[..., Any]) -> Callable[[F], F]:
    """Replace each parameter named in ``builders`` by its builder's parameters (in place, in
    their order); a call gathers them back into ``builder(**them)`` under the group's name."""

    def decorate(fn: F) -> F:
        params: list[inspect.Parameter] = []
        members: dict[str, list[str]] = {}
        for p in inspect.signature(fn, eval_str=True).parameters.values():
            if p.name not in builders:
                params.append(p)
                continue
            group = list(inspect.signature(builders[p.name], eval_str=True).parameters.values())
            members[p.name] = [q.name for q in group]
            params += [q.replace(kind=p.kind) for q in group]
        sig = inspect.signature(fn, eval_str=True).replace(parameters=params)

        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            for name, names in members.items():
                kwargs[name] = builders[name](**{n: kwargs.pop(n) for n in names if n in kwargs})
            return fn(*args, **kwargs)

        wrapper.__signature__ = sig  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in params}
        if sig.return_annotation is not sig.empty:
            wrapper.__annotations__["return"] = sig.return_annotation
        return wrapper  # type: ignore[return-value]

    return decorate
