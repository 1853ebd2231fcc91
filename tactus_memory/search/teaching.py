"""Objects you teach: a span of a session marked "holding <label>" becomes a search target.

``memory.teach("drill", session="bench", after=12.0, before=15.5)`` records that the touch
windows of ``bench`` overlapping ``[12.0, 15.5]`` were a grasp of a drill. From then on:

* **targets** of a touch sense are its trained classes (the checkpoint's template-averaged
  class phrases) and the taught labels (the same templates filled with the label, embedded
  by the memory's space on the document side);
* a text query is matched to its **nearest target** in the text space (raw cosine of the
  query embedding and the target phrase embedding);
* when that target is a taught label (or a trained class that was also taught) and the
  cosine is at least :data:`MIN_LABEL_COS`, touch hits are ranked by

      score(z) = W_TEXT * cos(z, text target) + W_PROTO * cos(z, prototype)

  where the text target is the label's phrase embedding centred like every touch query
  (``normalize(t - query_centroid)``) and the prototype is the normalised mean embedding of
  every stored window of the taught spans (centred on the other taught labels' prototypes
  when :data:`CENTRE_PROTOTYPES` is set: ``normalize(p - mean(others))``). With
  :data:`TEXT_AGREE_TOP` set (opt-in), a label that is no trained class counts its words only
  when its phrase is among the targets nearest its prototype, else ``W_TEXT`` is 0. For unit
  ``z`` that is one cosine with the query vector ``W_TEXT * target + W_PROTO * prototype``
  (normalised), so the ranking goes through the one ranked search path
  (:class:`~tactus_memory.search.ranking.Ranker`) unchanged;
* any other query (nearest target an untaught class, or too far from every target) is
  ranked as before.

Teachings are stored in the store's meta table (key ``taught/<id>``): each memory, so each
tenant, has its own; a key limited to a session prefix sees only the teachings of its
sessions. The prototype is read from the stored windows at query time (cached per store
version), so re-embedding moves it, and deleting a taught session removes its teaching.
"""

from __future__ import annotations

import json
import re
import threading
import time
import uuid
from typing import Any

import numpy as np
from typing_extensions import Unpack

from tactus_memory.errors import InvalidInputError, NotFoundError
from tactus_memory.limits import FORMAT_CHARS
from tactus_memory.names import validate_id
from tactus_memory.query import TeachSpan, teach_span
from tactus_memory.results import Teaching, label_key
from tactus_memory.senses.stored import SenseRegistry
from tactus_memory.spaces.base import Space
from tactus_memory.storage.retention import TAUGHT_PREFIX
from tactus_memory.storage.store import Store
from tactus_memory.where import Where, refuse_format_chars, session_visible

#: weight of the label's text target in the taught ranking (chosen with the benchmark,
#: ``benchmarks/teach.py``; the docs' "Objects you teach" reports the grid)
W_TEXT = 1.0
#: weight of the taught grasps' prototype (mean embedding of the taught windows)
W_PROTO = 1.0
#: centre a label's prototype on the other taught labels' (``p - mean(others)``, then unit),
#: so what every grasp shares (the sensor, the hand) pulls no label's question. Off: on the
#: protocol with made-up labels (``benchmarks/teach_once.py``, demo checkpoint) it kept top-1
#: at 3 of 26 and moved R@5 from 6 to 9 of 26, inside the noise; the docs' "Objects you teach"
CENTRE_PROTOTYPES = False
#: opt-in (``memory.teachings.agree_top = 3``): a taught label that is not one of the sense's
#: trained classes counts its words (``W_TEXT``) only when the taught grasps agree with them:
#: the label's phrase is among that many targets (trained classes and taught labels, centred)
#: nearest the label's prototype; otherwise the prototype alone ranks. A trained class's words
#: always count. Off (None: every label's words count), measured both ways: with made-up labels
#: (``benchmarks/teach_once.py``, demo checkpoint) 3 lifted R@5 from 6 to 11 of 26 (paired
#: +0.19, 95 % bootstrap [0.00, 0.38]) with top-1 3 of 26 either way, but on a 12x16 sensor's
#: small model a new word ("kettle", tests/service/test_sensor_serving.py) then found 3 of its
#: 5 first hits in the taught session where the test asks 4
TEXT_AGREE_TOP: int | None = None
#: a query steers toward a taught label only when its cosine to the label's phrase reaches
#: this (MiniLM: "when was I holding the drill?" vs "a hand holding a drill" ~0.6; an
#: unrelated question ~0.1-0.25)
MIN_LABEL_COS = 0.35
#: meta-table key prefix of a teaching
KEY_PREFIX = TAUGHT_PREFIX
MAX_LABEL_CHARS = 64
#: a label: no control characters, no format characters (limits.FORMAT_CHARS: a bidi
#: override or a zero-width space makes a label display as another), and not blank (the HTTP
#: schema carries the same pattern)
_NOT = rf"\x00-\x1f\x7f-\x9f{FORMAT_CHARS}"
LABEL_PATTERN = rf"^[^{_NOT}]*[^\s{_NOT}][^{_NOT}]*$"
#: the phrase of a label taught to a sense that has no phrase templates of its own
FALLBACK_PHRASE = "a hand holding {}"


def validate_label(label: Any) -> str:
    """A taught label: 1-64 characters, no control characters, not blank (LABEL_PATTERN);
    kept as given (stripped)."""
    if not isinstance(label, str) or not label.strip():
        raise InvalidInputError(f"a taught label must be a non-empty string, got {label!r}")
    out = label.strip()
    refuse_format_chars(label, "a taught label")
    if len(label) > MAX_LABEL_CHARS or not re.fullmatch(LABEL_PATTERN, label):
        raise InvalidInputError(
            f"a taught label must be 1-{MAX_LABEL_CHARS} printable characters, got {label!r}"
        )
    return out


class Teachings:
    """The teachings of one memory, and the query steering they give (``Ranker.steer``)."""

    def __init__(self, store: Store, registry: SenseRegistry, space: Space, lock: Any) -> None:
        self.store = store
        self.registry = registry
        self.space = space
        self.lock = lock
        self._text: dict[str, np.ndarray] = {}  # phrases -> (D,) raw phrase embedding
        self._protos: dict[str, tuple[int, np.ndarray | None]] = {}  # id -> (version, proto)
        self._cache_lock = threading.Lock()
        self._all: tuple[int, list[Teaching]] | None = None
        #: the rule's weights and bar (module defaults; the benchmark sweeps them)
        self.w_text, self.w_proto, self.min_cos = W_TEXT, W_PROTO, MIN_LABEL_COS
        self.centre = CENTRE_PROTOTYPES
        self.agree_top = TEXT_AGREE_TOP

    # ----------------------------------------------------------- records
    def teach(self, label: str, *, session: str, **span: Unpack[TeachSpan]) -> Teaching:
        """Mark the ``sense`` windows (default touch) of ``session`` overlapping ``[after,
        before]`` (:class:`~tactus_memory.query.TeachSpan`) as "holding ``label``": the label
        becomes a search target beside the sense's trained classes (the module's rule).
        Raises NotFoundError when no such window is stored, InvalidInputError on a bad label
        or span or a text sense."""
        after, before, sense = teach_span(span)
        label = validate_label(label)
        validate_id(session, "session")
        s = self.registry.search_sense(sense)  # UnknownSenseError names the registered ones
        if s.modality == "text":
            raise InvalidInputError("teach a span of a sensed modality (e.g. touch), not text")
        where = Where().session(session).sense(sense).overlaps(after, before)
        with self.lock:
            rows = self.store.scan(where.sql(), ["t", "t_end"]).to_pylist()
            if not rows:
                lo, hi = ("-inf" if after is None else after), ("inf" if before is None else before)
                shown = f"[{lo}, {hi}]"
                raise NotFoundError(
                    f"no {sense!r} items of session {session!r} overlap {shown}: nothing to teach"
                )
            t = float(after) if after is not None else min(r["t"] for r in rows)
            t_end = float(before) if before is not None else max(r["t_end"] for r in rows)
            item = Teaching(
                id=uuid.uuid4().hex,
                label=label,
                session=session,
                sense=sense,
                t=t,
                t_end=t_end,
                windows=len(rows),
                created=time.time(),
            )
            self.store.set_meta(KEY_PREFIX + item.id, json.dumps(item.to_dict()))
        return item

    def _records(self) -> list[Teaching]:
        """Every teaching of this memory, cached per meta-table version."""
        version = self.store.meta_version()
        with self._cache_lock:
            if self._all is not None and self._all[0] == version:
                return self._all[1]
        out = []
        for raw in self.store.meta_items(KEY_PREFIX).values():
            try:
                out.append(Teaching(**json.loads(raw)))
            except (TypeError, ValueError):
                continue  # a record of a later version: not ours to read
        with self._cache_lock:
            self._all = (version, out)
        return out

    def taught(self, sense: str | None = None, label: str | None = None) -> list[Teaching]:
        """Every teaching (of ``sense``, of ``label``) of the sessions this context sees,
        oldest first."""
        out = []
        for t in self._records():
            if not session_visible(t.session):
                continue
            if sense is not None and t.sense != sense:
                continue
            if label is not None and label_key(t.label) != label_key(label):
                continue
            out.append(t)
        return sorted(out, key=lambda t: (t.created, t.id))

    def forget(self, label: str | None = None, *, id: str | None = None) -> int:  # noqa: A002
        """Delete the teachings of ``label`` (or the one ``id``); returns how many."""
        if (label is None) == (id is None):
            raise InvalidInputError("forget needs exactly one of a label or id=")
        doomed = [t for t in self.taught() if (t.id == id if id is not None else True)]
        if label is not None:
            doomed = [t for t in doomed if label_key(t.label) == label_key(label)]
        with self.lock:
            for t in doomed:
                self.store.delete_meta(KEY_PREFIX + t.id)
        return len(doomed)

    def drop_session(self, session: str) -> int:
        """Forget every teaching of ``session`` (its windows are gone)."""
        doomed = [t for t in self.taught() if t.session == session]
        for t in doomed:
            self.store.delete_meta(KEY_PREFIX + t.id)
        return len(doomed)

    def labels(self, sense: str) -> list[str]:
        """The distinct taught labels of ``sense`` (first spelling of each), sorted."""
        seen: dict[str, str] = {}
        for t in self.taught(sense):
            seen.setdefault(label_key(t.label), t.label)
        return sorted(seen.values())

    # ----------------------------------------------------------- prototypes and targets
    def _prototype(self, t: Teaching, version: int) -> np.ndarray | None:
        """Sum of the taught span's stored window vectors (None: none left)."""
        with self._cache_lock:
            hit = self._protos.get(t.id)
        if hit is not None and hit[0] == version:
            return hit[1]
        where = Where().session(t.session).sense(t.sense).overlaps(t.t, t.t_end)
        tab = self.store.scan(where.sql(), ["vector"])
        if tab.num_rows == 0:
            proto = None
        else:
            proto = np.asarray(tab.column("vector").to_pylist(), np.float32).sum(axis=0)
        with self._cache_lock:
            self._protos[t.id] = (version, proto)
        return proto

    def prototypes(self, sense: str) -> dict[str, tuple[str, np.ndarray]]:
        """label key -> (label, (D,) unit mean embedding of its taught windows)."""
        version = self.store.version()
        sums: dict[str, tuple[str, np.ndarray]] = {}
        for t in self.taught(sense):
            p = self._prototype(t, version)
            if p is None:
                continue
            key = label_key(t.label)
            prev = sums.get(key)
            sums[key] = (t.label, p if prev is None else prev[1] + p)
        return {k: (name, _unit(v)) for k, (name, v) in sums.items() if np.linalg.norm(v) > 0}

    def text_target(self, label: str, sense: str) -> np.ndarray:
        """(D,) unit raw phrase embedding of a label: the sense's class templates filled with
        it (``target_phrases``; a sense without them: :data:`FALLBACK_PHRASE`), averaged."""
        live = self.registry.senses.get(sense)
        phrases_of = getattr(live, "target_phrases", None)
        phrases = phrases_of(label) if callable(phrases_of) else [FALLBACK_PHRASE.format(label)]
        key = "\n".join(phrases)
        with self._cache_lock:
            hit = self._text.get(key)
        if hit is None:
            emb = np.asarray(self.space.embed_texts(phrases, query=False), np.float32)
            hit = _unit(emb.mean(axis=0))
            with self._cache_lock:
                self._text[key] = hit
        return hit

    def targets(self, sense: str, taught: bool = True) -> tuple[list[str], list[str], np.ndarray]:
        """Every search target of ``sense``: (names, kinds "class"/"taught", (C, D) raw);
        ``taught=False``: its trained classes only."""
        names: list[str] = []
        kinds: list[str] = []
        rows: list[np.ndarray] = []
        s = self.registry.senses.get(sense)
        class_targets = getattr(s, "class_targets", None)
        if callable(class_targets):
            classes, raw = class_targets()
            names += list(classes)
            kinds += ["class"] * len(classes)
            rows += list(np.asarray(raw, np.float32))
        have = {label_key(n) for n in names}
        for label in self.labels(sense) if taught else []:
            if label_key(label) in have:
                continue
            names.append(label)
            kinds.append("taught")
            rows.append(self.text_target(label, sense))
        dim = int(self.space.dim)
        return names, kinds, (np.stack(rows) if rows else np.zeros((0, dim), np.float32))

    def steer(self, q: np.ndarray, sense: str, transformed: np.ndarray) -> np.ndarray:
        """The (1, D) query vector sense ``sense`` is searched with: ``transformed`` (its own
        query transform of the text query ``q``), or, when ``q``'s nearest target is taught,
        ``normalize(W_TEXT * centred target + W_PROTO * prototype)``."""
        protos = self.prototypes(sense)
        if not protos:
            return transformed
        names, kinds, raw = self.targets(sense)
        cos = raw @ np.asarray(q, np.float32).reshape(-1)
        j = int(np.argmax(cos))
        key = label_key(names[j])
        if cos[j] < self.min_cos or key not in protos:
            return transformed
        centroid = self.registry.search_sense(sense).query_centroid
        target = raw[j] if centroid is None else raw[j] - np.asarray(centroid, np.float32)
        proto = protos[key][1]
        others = [p for k, (_, p) in protos.items() if k != key]
        if self.centre and others:
            proto = _unit(proto - np.mean(others, axis=0))
        # a trained class's words carry what the encoder was trained on; a new word's only
        # what the taught grasps agree with
        agrees = kinds[j] == "class" or self.text_agrees(j, protos[key][1], raw, centroid)
        w_text = self.w_text if agrees else 0.0
        mixed = w_text * _unit(target) + self.w_proto * proto
        return _unit(mixed).reshape(1, -1)

    def text_agrees(
        self, j: int, proto: np.ndarray, raw: np.ndarray, centroid: np.ndarray | None
    ) -> bool:
        """Whether target ``j``'s phrase is among the :data:`TEXT_AGREE_TOP` targets (raw (C, D)
        phrase embeddings, centred like a query) nearest the label's (D,) prototype."""
        if self.agree_top is None:
            return True
        c = raw if centroid is None else raw - np.asarray(centroid, np.float32)
        cos = (c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)) @ proto
        return bool((cos > cos[j]).sum() < self.agree_top)


def _unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float32)
    n = float(np.linalg.norm(x))
    return x / n if n > 0 else x
