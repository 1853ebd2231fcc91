"""Touch found in words by its facets: each touch window's caption (its facets in words,
:func:`tactus_memory.touch.facets.caption`, e.g. "a firm pinch with thumb and index,
squeezing hard") is embedded in the memory's text space and searched with the other senses,
so "pinching something small" or "squeezing hard" finds grasps whatever object the touch
encoder thinks they held.

**Where the embeddings live.** A window's caption is a function of three stored facet
columns: its ``peak`` band (light / steady / firm), its ``grip`` and its active ``regions``
(most loaded first, the column's own form). So a store has few distinct captions (tens),
however many windows: each one's embedding is kept once, in the store's meta table under
``caption/<rule>/<digest>`` (:data:`CAPTION_PREFIX`), with its key. A write adds the captions
it brings that the store lacks (embedded before the rows are stored, so a stored window's
caption is always there); ``tactus maintain --facets`` rebuilds them all from the stored
facets. Entries of another caption rule (``touch.facets.CAPTION_RULE``) are never read, so a
new rule takes effect after ``tactus maintain --facets``, which writes the new rule's and
removes the old.

**How they are searched.** A text query's embedding (before any sense's query transform) is
compared with every caption of the current rule; those at cosine >= :data:`CAPTION_MIN_COS`
(at most :data:`CAPTION_TOP`, best first) bring their windows within the question's scope
(a scan on the facet columns, at most ``k`` per caption). A caption's cosine is calibrated as
a sense's is (:func:`~tactus_memory.search.scoring.estimate`: the probe queries against the
store's captions), and a window's score is the higher of its encoder score and its caption's.
A grasp (:mod:`tactus_memory.search.grasps`) scores the higher of its pooled encoder score
and its best member window's caption score.
"""

from __future__ import annotations

import base64
import hashlib
import json
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.search.scoring import Calibration, estimate
from tactus_memory.storage.tables import HIT_COLUMNS
from tactus_memory.touch.facets import (
    CAPTION_RULE,
    FIRMNESS_BANDS,
    caption,
    facet_columns,
    firmness,
)
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Where, sessions_under

if TYPE_CHECKING:
    from tactus_memory.senses.stored import SenseRegistry
    from tactus_memory.spaces.base import Space
    from tactus_memory.storage.store import Store

#: meta-table key prefix of a caption's embedding (then ``<rule>/<digest of its key>``)
CAPTION_PREFIX = "caption/"
#: a caption takes part in a search only at this cosine to the query or above. MiniLM, rule
#: 2: physical questions reach their caption at 0.67-0.93 ("pinching something small" 0.68,
#: "squeezing hard" 0.71, "light touches" 0.67, "a pinch with thumb and index" 0.93);
#: object questions stay under ("a pen" 0.49, "holding a mug" 0.42, "holding something"
#: 0.46), so a question about an object is answered by the touch encoder alone
CAPTION_MIN_COS = 0.55
#: the most captions one question reads windows of
CAPTION_TOP = 8


@dataclass(frozen=True)
class CaptionKey:
    """What a window's caption is a function of: its firmness band, grip and active
    regions (the ``regions`` column's form, ``",thumb,index,"``)."""

    band: str
    grip: str | None
    regions: str

    @classmethod
    def of(cls, facets: dict[str, Any]) -> CaptionKey:
        """The key of one window's facet columns (``peak``, ``grip``, ``regions``)."""
        return cls(firmness(facets.get("peak")), facets.get("grip"), facets.get("regions") or ",")

    def digest(self) -> str:
        text = json.dumps([self.band, self.grip, self.regions])
        return hashlib.sha1(text.encode()).hexdigest()[:16]  # noqa: S324 (a name, not a secret)

    def caption(self) -> str:
        """The caption of every window of this key (:func:`touch.facets.caption`)."""
        names = [r for r in self.regions.split(",") if r]
        lo, hi = FIRMNESS_BANDS[self.band]
        peak = lo if lo is not None else 0.0
        # shares in the stored order, each active (>= ACTIVE_SHARE): the caption's order
        shares = {r: 1.0 - 0.01 * i for i, r in enumerate(names)}
        return caption({"peak": peak, "grip": self.grip, "regions": shares})

    def where(self, base: Where) -> Where:
        lo, hi = FIRMNESS_BANDS[self.band]
        return base.copy().caption_key(self.grip, self.regions, lo, hi)


@dataclass
class Vocabulary:
    """The store's captions of the current rule: keys, texts, (V, D) unit embeddings and
    their calibration."""

    keys: list[CaptionKey]
    texts: list[str]
    vectors: np.ndarray
    calibration: Calibration


class Captions:
    """A store's caption embeddings (the module docstring): added by writes, rebuilt by
    ``tactus maintain --facets``, searched by the ranked search path."""

    def __init__(self, store: Store, space: Space, registry: SenseRegistry | None = None) -> None:
        """``registry`` gives the probe queries a search calibrates with (None: writes and
        rebuilds only)."""
        self.store = store
        self.registry = registry
        self.space = space
        self._lock = threading.Lock()
        self._vocab: tuple[int, Vocabulary | None] | None = None  # (meta version, vocabulary)
        self._known: set[str] = set()  # digests known stored (a write asks the store once)

    # ----------------------------------------------------------- writes
    def add(self, extras: Sequence[dict[str, Any]]) -> int:
        """Embed and store the captions of the windows ``extras`` (their stored columns: a
        touch window's facet columns; others are skipped) that the store lacks; returns how
        many were added."""
        keys = {CaptionKey.of(e) for e in extras if e.get("facets") is not None}
        if all(k.digest() in self._known for k in keys):
            return 0
        self._known |= self._stored_digests()
        new = sorted((k for k in keys if k.digest() not in self._known), key=CaptionKey.digest)
        if not new:
            return 0
        texts = [k.caption() for k in new]
        vecs = as_unit_rows(self.space.embed_texts(texts), self.space.dim, what="captions")
        values = {
            f"{CAPTION_PREFIX}{CAPTION_RULE}/{k.digest()}": json.dumps(
                {
                    "band": k.band,
                    "grip": k.grip,
                    "regions": k.regions,
                    "caption": text,
                    "vector": base64.b64encode(v.astype("<f4").tobytes()).decode(),
                }
            )
            for k, text, v in zip(new, texts, vecs, strict=True)
        }
        self.store.set_meta_many(values)
        self._known |= {k.digest() for k in new}
        return len(new)

    def rebuild(self) -> dict[str, int]:
        """Every caption of the stored touch windows' facets, of the current rule; entries of
        other rules removed (``tactus maintain --facets``). Returns the counts."""
        with sessions_under(None):
            tbl = self.store.scan("facets IS NOT NULL", ["peak", "grip", "regions", "facets"])
        rows = tbl.to_pylist()
        stale = [k for k in self.store.meta_items(CAPTION_PREFIX) if not self._current(k)]
        for key in stale:
            self.store.delete_meta(key)
        self._known.clear()
        added = self.add(rows)
        return {"captions": len(self._stored_digests()), "added": added, "removed": len(stale)}

    @staticmethod
    def _current(key: str) -> bool:
        return key.startswith(f"{CAPTION_PREFIX}{CAPTION_RULE}/")

    def _stored_digests(self) -> set[str]:
        return {
            k.rsplit("/", 1)[1] for k in self.store.meta_items(CAPTION_PREFIX) if self._current(k)
        }

    # ----------------------------------------------------------- search
    def vocabulary(self) -> Vocabulary | None:
        """The current rule's captions (cached per meta-table version); None: none."""
        if not self.store.exists:
            return None
        version = self.store.meta_version()
        with self._lock:
            if self._vocab is not None and self._vocab[0] == version:
                return self._vocab[1]
        entries = [
            json.loads(v)
            for k, v in self.store.meta_items(CAPTION_PREFIX).items()
            if self._current(k)
        ]
        vocab = None
        if entries:
            vecs = np.stack(
                [np.frombuffer(base64.b64decode(e["vector"]), dtype="<f4") for e in entries]
            )
            vecs = as_unit_rows(vecs, self.space.dim, what="captions")
            if self.registry is None:
                raise RuntimeError("searching captions needs the sense registry's probes")
            probes = self.registry.probe_vectors()
            vocab = Vocabulary(
                keys=[CaptionKey(e["band"], e["grip"], e["regions"]) for e in entries],
                texts=[e["caption"] for e in entries],
                vectors=vecs,
                calibration=estimate(probes, vecs, len(entries)),
            )
        with self._lock:
            self._vocab = (version, vocab)
        return vocab

    def scores(self, q: np.ndarray) -> dict[CaptionKey, tuple[float, float]]:
        """The captions the (1, D) text query ``q`` reaches (cosine >= CAPTION_MIN_COS), at
        most CAPTION_TOP: key -> (calibrated score, cosine)."""
        vocab = self.vocabulary()
        if vocab is None:
            return {}
        cos = vocab.vectors @ np.asarray(q, np.float32).reshape(-1)  # (V,)
        best = [int(i) for i in np.argsort(-cos)[:CAPTION_TOP] if cos[i] >= CAPTION_MIN_COS]
        return {
            vocab.keys[i]: (float(vocab.calibration.score(float(cos[i]))), float(cos[i]))
            for i in best
        }

    def merge(
        self,
        scored: list[tuple[float, float, dict[str, Any]]],
        q: np.ndarray,
        k: int,
        senses: Sequence[str],
        base: Where,
    ) -> list[tuple[float, float, dict[str, Any]]]:
        """``scored`` (a ranked search's ``(score, cosine, row)``) with the windows the
        query's captions find (:meth:`search`): a window found both ways keeps the higher
        score."""
        found = self.search(q, k, senses, base)
        if not found:
            return scored
        by_id = {row["id"]: (score, cos, row) for score, cos, row in scored}
        for score, cos, row in found:
            have = by_id.get(row["id"])
            if have is None or score > have[0]:
                by_id[row["id"]] = (score, cos, row)
        return list(by_id.values())

    def search(
        self, q: np.ndarray, k: int, senses: Sequence[str], base: Where
    ) -> list[tuple[float, float, dict[str, Any]]]:
        """Windows of ``senses`` in ``base``'s scope whose caption the (1, D) text query
        reaches: ``(score, cosine, row)`` each, at most ``k`` per caption."""
        out: list[tuple[float, float, dict[str, Any]]] = []
        if not senses or "facets" not in self.store.schema.names:
            return out
        for key, (score, cos) in self.scores(q).items():
            where = key.where(base).senses(senses)
            tbl = self.store.scan(where.sql(), HIT_COLUMNS, limit=k)
            out.extend((score, cos, row) for row in tbl.to_pylist())
        return out

    @staticmethod
    def grasp_score(
        reached: dict[CaptionKey, tuple[float, float]], facets: Sequence[str | None] | None
    ) -> tuple[float, float] | None:
        """The best ``(score, cosine)`` of a grasp's member windows' captions (from their
        stored facets JSON) among those a query ``reached`` (:meth:`scores`); None: none."""
        if not reached or not facets:
            return None
        best: tuple[float, float] | None = None
        for f in facets:
            if f is None:
                continue
            hit = reached.get(CaptionKey.of(facet_columns(json.loads(f))))
            if hit is not None and (best is None or hit[0] > best[0]):
                best = hit
        return best
