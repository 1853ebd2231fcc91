"""The teaching calls of :class:`~tactus_memory.client.main.Client` (``POST /sessions/{id}/labels``,
``GET /labels``, ``DELETE /labels/{id}``), the same as :meth:`Memory.teach`, ``taught`` and
``forget``."""

from __future__ import annotations

from typing import Any

import httpx
from typing_extensions import Unpack

from tactus_memory.errors import InvalidInputError
from tactus_memory.query import TeachSpan, teach_span
from tactus_memory.results import Teaching, label_key

__all__ = ["Teaching", "TeachingCalls"]


class TeachingCalls:
    """Mixed into the Client, whose ``request``/``_get`` these use."""

    def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        raise NotImplementedError

    def _get(self, path: str, params: Any = None) -> Any:
        raise NotImplementedError

    def teach(self, label: str, *, session: str, **span: Unpack[TeachSpan]) -> Teaching:
        """:meth:`Memory.teach` over HTTP (``POST /sessions/{id}/labels``); keywords
        ``after``, ``before``, ``sense``."""
        after, before, sense = teach_span(span)
        body = {"label": label, "t": after, "t_end": before, "sense": sense}
        return Teaching(**self.request("POST", f"/sessions/{session}/labels", json=body).json())

    def taught(self, sense: str | None = None) -> list[Teaching]:
        """Every teaching (of ``sense``), oldest first (``GET /labels``)."""
        got = self._get("/labels", {} if sense is None else {"sense": sense})["labels"]
        return [Teaching(**t) for t in got]

    def forget(self, label: str | None = None, *, id: str | None = None) -> int:  # noqa: A002
        """Delete the teachings of ``label`` (or the one ``id``); returns how many."""
        if (label is None) == (id is None):
            raise InvalidInputError("forget needs exactly one of a label or id=")
        doomed = [
            t.id
            for t in self.taught()
            if t.id == id or label_key(t.label) == label_key(label or "")
        ]
        for one in doomed:
            self.request("DELETE", f"/labels/{one}")
        return len(doomed)
