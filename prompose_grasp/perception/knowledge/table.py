"""The object-knowledge table: what an everyday object named in a prompt usually looks like.

`objects.json` beside this module (docs/knowledge.md) lists everyday objects with their synonyms, typical
metric size ranges, typical colours (palette names of `grounding.describe.PALETTE`), coarse shape and
features. `ObjectKnowledge.lookup(noun)` retrieves what the table knows for a prompt's noun with the sentence
encoder: a name or synonym of the table gives its entry at full weight; a name the table has never seen
falls to its nearest entries (merged where several are about as near) at a lower weight, and to nothing
when no entry is near (`KnowledgeMatch.weight`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp._cache import cache_dir
from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.grounding.describe import PALETTE as _PALETTE  # the names an entry may list

__all__ = [
    "CATEGORIES",
    "COARSE_SHAPES",
    "FEATURES",
    "TABLE_PATH",
    "KnowledgeMatch",
    "ObjectEntry",
    "ObjectKnowledge",
    "cache_dir",
    "load_table",
]

log = logging.getLogger(__name__)

TABLE_PATH = Path(__file__).resolve().parent / "objects.json"

COARSE_SHAPES = ("box", "cylinder", "round", "flat", "elongated", "irregular")
#: "lies": it rests on its long side and never stands on its end by itself (a banana, a knife, a pen): its
#: shortest extent is its height above a support.
FEATURES = ("handle", "hollow", "lid", "cap", "spout", "neck", "lies")
CATEGORIES = (
    "household", "grocery", "kitchen", "bathroom", "office", "tool", "toy", "food", "electronics", "clothing",
    "sports", "warehouse",
)  # fmt: skip
_KEYS = frozenset({"name", "synonyms", "category", "size_m", "colours", "shape", "features", "rigid"})

#: Retrieval (cosine of MiniLM sentence embeddings of the noun and of each entry's name and synonyms).
#: At or above `FULL_MATCH` the noun is that entry (a name, a synonym, a plural or a word-order variant:
#: "cans of tuna" ~ "tuna can"); below `NO_MATCH` no entry is near enough to say anything; in between the
#: weight falls linearly. Entries within `MERGE_BAND` of the best are merged (their ranges joined): for an
#: unseen name the nearest kinds together are a safer guess than any one of them.
FULL_MATCH = 0.85
NO_MATCH = 0.55
MERGE_BAND = 0.04


@dataclass(frozen=True)
class ObjectEntry:
    """One kind of object.

    Attributes:
        name: the plain name ("tuna can").
        synonyms: other names for it ("can of tuna").
        category: one of `CATEGORIES`.
        size_lo_m, size_hi_m: (3,) float64 [m] the typical range of its three full extents, largest first
            (orientation-free: the longest dimension, the middle one, the shortest).
        colours: palette names it usually shows over most of its surface, most typical first; () for any.
        shape: one of `COARSE_SHAPES`.
        features: a subset of `FEATURES`.
        rigid: False for bags, sacks, soft toys and clothing.
    """

    name: str
    synonyms: tuple[str, ...]
    category: str
    size_lo_m: np.ndarray
    size_hi_m: np.ndarray
    colours: tuple[str, ...]
    shape: str
    features: tuple[str, ...]
    rigid: bool

    @property
    def typical_size_m(self) -> np.ndarray:
        """(3,) the middle of each range [m], largest first."""
        return 0.5 * (self.size_lo_m + self.size_hi_m)


@dataclass(frozen=True)
class KnowledgeMatch:
    """What the table knows for one noun.

    Attributes:
        noun: the noun looked up.
        entries: the entries it matched, nearest first (more than one when several were about as near).
        similarity: the cosine of the nearest.
        weight: in (0, 1]: 1 for a name or synonym of the table, lower for the nearest of an unseen name.
        size_lo_m, size_hi_m: (3,) [m] the joined size range of the entries, largest first.
        colours: the entries' colours joined; () when any entry comes in any colour.
        shapes: the entries' coarse shapes.
    """

    noun: str
    entries: tuple[ObjectEntry, ...]
    similarity: float
    weight: float
    size_lo_m: np.ndarray
    size_hi_m: np.ndarray
    colours: tuple[str, ...]
    shapes: tuple[str, ...]

    @property
    def entry(self) -> ObjectEntry:
        """The nearest entry."""
        return self.entries[0]

    @property
    def lies(self) -> bool:
        """Every entry rests on its long side (feature "lies"): the shortest range is a height."""
        return all("lies" in e.features for e in self.entries)


def _entry(raw: Any, index: int) -> ObjectEntry:
    where = f"objects.json entry {index}"
    if not isinstance(raw, dict) or set(raw) != _KEYS:
        raise InvalidInputError(f"{where} must have exactly the keys {sorted(_KEYS)}, got {raw!r:.200}")
    name = raw["name"]
    if not isinstance(name, str) or not name.strip() or name != name.lower():
        raise InvalidInputError(f"{where}: name must be a lower-case non-blank string, got {name!r}")
    where = f"objects.json entry {name!r}"
    size = np.asarray(raw["size_m"], dtype=np.float64)
    if size.shape != (3, 2) or not np.all(np.isfinite(size)) or np.any(size <= 0):
        raise InvalidInputError(f"{where}: size_m must be 3 [min, max] pairs of positive metres")
    if np.any(size[:, 0] > size[:, 1]):
        raise InvalidInputError(f"{where}: size_m has a range with min > max")
    mid = size.mean(axis=1)
    if np.any(np.diff(mid) > 1e-9):
        raise InvalidInputError(f"{where}: size_m must be sorted largest first, got {size.tolist()}")
    for key, allowed in (("colours", _PALETTE), ("features", FEATURES)):
        bad = [v for v in raw[key] if v not in allowed]
        if bad:
            raise InvalidInputError(f"{where}: {key} {bad} not among {', '.join(allowed)}")
    if raw["shape"] not in COARSE_SHAPES:
        raise InvalidInputError(f"{where}: shape {raw['shape']!r} not among {', '.join(COARSE_SHAPES)}")
    if raw["category"] not in CATEGORIES:
        raise InvalidInputError(f"{where}: category {raw['category']!r} not among {', '.join(CATEGORIES)}")
    if not isinstance(raw["rigid"], bool):
        raise InvalidInputError(f"{where}: rigid must be true or false")
    return ObjectEntry(
        name=name,
        synonyms=tuple(str(s) for s in raw["synonyms"]),
        category=raw["category"],
        size_lo_m=size[:, 0].copy(),
        size_hi_m=size[:, 1].copy(),
        colours=tuple(raw["colours"]),
        shape=raw["shape"],
        features=tuple(raw["features"]),
        rigid=raw["rigid"],
    )


def load_table(path: str | Path | None = None) -> tuple[ObjectEntry, ...]:
    """The entries of a knowledge table file (default: the shipped `objects.json`), validated.

    Raises:
        InvalidInputError: a missing file, bad JSON, or an entry that breaks the schema (docs/knowledge.md);
            the message names the entry.
    """
    return _shipped() if path is None else _load(Path(path))


@lru_cache(maxsize=1)
def _shipped() -> tuple[ObjectEntry, ...]:
    return _load(TABLE_PATH)


def _load(p: Path) -> tuple[ObjectEntry, ...]:
    try:
        raw = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InvalidInputError(f"cannot read the knowledge table {p}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"the knowledge table {p} is not valid JSON: {exc}") from None
    if not isinstance(raw, list) or not raw:
        raise InvalidInputError(f"the knowledge table {p} must be a non-empty JSON list of entries")
    entries = tuple(_entry(r, i) for i, r in enumerate(raw))
    seen: dict[str, str] = {}
    for e in entries:
        for text in (e.name, *e.synonyms):
            owner = seen.setdefault(text, e.name)
            if owner != e.name:
                raise InvalidInputError(f"the knowledge table names {text!r} twice ({owner!r}, {e.name!r})")
    return entries


class ObjectKnowledge:
    """Retrieval over the knowledge table with a sentence encoder (module docstring).

    Args:
        encoder: any `perception.text.TextEncoder` (the grounder's; its embeddings are unit length).
        entries: the table (default: the shipped one).
    """

    def __init__(self, encoder: Any, entries: tuple[ObjectEntry, ...] | None = None):
        self.encoder = encoder
        self.entries = entries if entries is not None else load_table()
        self._texts: list[str] = []
        self._owner: list[int] = []
        for i, e in enumerate(self.entries):
            for text in (e.name, *e.synonyms):
                self._texts.append(text)
                self._owner.append(i)
        self._owner_arr = np.asarray(self._owner)
        self._E: np.ndarray | None = None
        self._cache: dict[str, KnowledgeMatch | None] = {}
        self._lock = threading.Lock()

    def _embeddings(self) -> np.ndarray:
        with self._lock:
            if self._E is None:
                self._E = _cached_embeddings(self.encoder, self._texts)
            return self._E

    def warm_up(self) -> None:
        """Embed the table's names and synonyms now: read from the embedding cache when this encoder has
        embedded this table before (`cache_dir`), else computed (~2,700 short texts, seconds on 2 cores)
        and stored there."""
        self._embeddings()

    def lookup(self, noun: str) -> KnowledgeMatch | None:
        """What the table knows for `noun` ("tuna can"), or None when no entry is near (module docstring)."""
        if not isinstance(noun, str):
            raise InvalidInputError(f"noun must be a str, got {type(noun).__name__}")
        key = " ".join(noun.lower().split())
        if not key:
            return None
        if key in self._cache:
            return self._cache[key]
        sims_text = self._embeddings() @ np.asarray(self.encoder.encode([key])[0], dtype=np.float64)
        exact = [self._owner[i] for i, t in enumerate(self._texts) if t == key]
        per_entry = np.full(len(self.entries), -1.0)
        np.maximum.at(per_entry, self._owner_arr, sims_text)
        if exact:  # a name of the table is that entry, whatever its neighbours' embeddings say
            per_entry[exact[0]] = max(per_entry[exact[0]], 1.0)
        best = float(per_entry.max())
        out = None
        if best > NO_MATCH:
            if best >= FULL_MATCH:
                chosen = [int(np.argmax(per_entry))]
                weight = 1.0
            else:
                near = np.flatnonzero(per_entry >= best - MERGE_BAND)
                chosen = [int(i) for i in near[np.argsort(-per_entry[near])]]
                weight = (best - NO_MATCH) / (FULL_MATCH - NO_MATCH)
            out = _joined(key, tuple(self.entries[i] for i in chosen), min(best, 1.0), weight)
        with self._lock:
            self._cache[key] = out
        return out


def _cached_embeddings(encoder: Any, texts: list[str]) -> np.ndarray:
    """(N, D) float64 embeddings of `texts`, from the cache when the same encoder embedded the same texts
    before. The key is the texts, the encoder's class, model folder and width, and its embedding of one
    probe text (a changed model under the same folder gives another key). A missing, stale or unreadable
    entry is computed; a cache that cannot be written is skipped; each with a log line, never an error."""
    probe = np.asarray(encoder.encode(["object knowledge cache probe"])[0], dtype=np.float32)
    h = hashlib.sha256()
    h.update(json.dumps(texts).encode())
    h.update(f"{type(encoder).__name__}|{getattr(encoder, 'model_path', '')}|{encoder.dim}".encode())
    h.update(np.round(probe, 5).tobytes())
    path = cache_dir() / f"knowledge-{h.hexdigest()[:20]}.npy"
    try:
        E = np.load(path)
        if E.shape == (len(texts), encoder.dim) and np.all(np.isfinite(E)):
            return E.astype(np.float64)
        log.info("knowledge embedding cache %s does not fit the table; embedding again", path)
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as exc:
        log.info("knowledge embedding cache %s unreadable (%s); embedding again", path, exc)
    E = np.asarray(encoder.encode(texts), dtype=np.float32)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
        np.save(tmp, E)
        os.replace(tmp, path)
    except OSError as exc:
        log.info("knowledge embedding cache not written (%s): the table is embedded at every start", exc)
    return E.astype(np.float64)


def _joined(noun: str, entries: tuple[ObjectEntry, ...], similarity: float, weight: float) -> KnowledgeMatch:
    lo = np.min([e.size_lo_m for e in entries], axis=0)
    hi = np.max([e.size_hi_m for e in entries], axis=0)
    colours: tuple[str, ...] = ()
    if all(e.colours for e in entries):
        colours = tuple(dict.fromkeys(c for e in entries for c in e.colours))
    shapes = tuple(dict.fromkeys(e.shape for e in entries))
    return KnowledgeMatch(noun, entries, similarity, float(weight), lo, hi, colours, shapes)
