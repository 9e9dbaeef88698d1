"""Sentence embeddings kept on disk between processes, one file per encoder identity.

A cold `ProMPose.default()` embedded ~500 fixed phrases (the grounder's description vocabulary, the shape
families' sentences and names, the prior library's descriptions) with MiniLM at every start: ~5 s on 2
cores, plus ~5 s to import and load the model. The phrases and the model only change with a new release or
another model folder, so their embeddings are stored under the user cache directory (`_cache.cache_dir`),
in a file named by the encoder's identity (`MiniLMTextEncoder.cache_key`: model folder, its config,
tokenizer and weights file, and this implementation's version). A prompt embedded once is stored too, so
a repeated prompt needs no model at all.

Failure is never an error: a missing, unreadable or mismatched file is recomputed and a file that cannot
be written is skipped, each with a log line. Concurrent writers merge what is on disk before replacing the
file atomically, so one process never loses another's rows (a row written twice is the same number).
"""

from __future__ import annotations

import atexit
import logging
import os
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["EmbeddingStore"]

log = logging.getLogger(__name__)

#: Rows kept in memory before they are written (and at the latest `_FLUSH_AFTER_S` after the first one, or
#: at exit): warming up encodes ~60 small batches, and rewriting the ~5 MB file after each would cost more
#: than the embeddings themselves.
_FLUSH_ROWS = 256
_FLUSH_AFTER_S = 2.0
#: A store holds at most this many texts (~77 MB at 384-d float32); past it, new rows are not written.
MAX_ROWS = 50_000


class EmbeddingStore:
    """text -> (D,) float32 unit embedding, read from and written to one `.npz` file.

    Args:
        path: the file (`texts`: (N,) str, `embeddings`: (N, D) float32).
        dim: the embedding width D; a file of another width is ignored (recomputed) with a log line.
        shipped: a read-only file of the same format installed with the package (the fixed vocabularies,
            `perception.shipped_embeddings`), read under `path`'s rows; used only when its `key` entry is
            `shipped_key` (the encoder it was computed with).
    """

    def __init__(self, path: Path, dim: int, shipped: Path | None = None, shipped_key: str = ""):
        self.path = Path(path)
        self.dim = int(dim)
        self.shipped = shipped
        self.shipped_key = shipped_key
        self._rows: dict[str, np.ndarray] | None = None
        self._pending: dict[str, np.ndarray] = {}
        self._first_pending_s = 0.0
        self._writable = True
        self._lock = threading.Lock()
        self._exit_hook = False

    def _read(self, path: Path | None = None, key: str | None = None) -> dict[str, np.ndarray]:
        path = path or self.path
        try:
            with np.load(path, allow_pickle=False) as z:
                texts, E = z["texts"], z["embeddings"]
                if key is not None and str(z["key"]) != key:
                    log.info("shipped embeddings %s are of another encoder; embedding again", path)
                    return {}
        except FileNotFoundError:
            return {}
        except (OSError, ValueError, KeyError) as exc:
            log.info("embedding cache %s unreadable (%s); embedding again", path, exc)
            return {}
        if E.ndim != 2 or E.shape != (len(texts), self.dim) or not np.all(np.isfinite(E)):
            log.info(
                "embedding cache %s does not fit this encoder (shape %s); embedding again", path, E.shape
            )
            return {}
        return {str(t): e for t, e in zip(texts.tolist(), E.astype(np.float32))}

    def _read_all(self) -> dict[str, np.ndarray]:
        rows = {} if self.shipped is None else self._read(self.shipped, self.shipped_key)
        rows.update(self._read())
        return rows

    def get(self, texts: Sequence[str]) -> dict[str, np.ndarray]:
        """The stored embeddings of those `texts` that are stored (the file is read on the first call)."""
        with self._lock:
            if self._rows is None:
                self._rows = self._read_all()
            return {t: self._rows[t] for t in texts if t in self._rows}

    def put(self, texts: Sequence[str], embeddings: np.ndarray) -> None:
        """Keep (N, D) `embeddings` of `texts`; written to the file in batches (module docstring)."""
        E = np.asarray(embeddings, dtype=np.float32).reshape(len(texts), self.dim)
        with self._lock:
            if self._rows is None:
                self._rows = self._read_all()
            new = {t: e for t, e in zip(texts, E) if t not in self._rows}
            if not new:
                return
            if not self._pending:
                self._first_pending_s = time.monotonic()
            self._rows.update(new)
            self._pending.update(new)
            if not self._exit_hook:
                atexit.register(self.flush)
                self._exit_hook = True
            due = (
                len(self._pending) >= _FLUSH_ROWS or time.monotonic() - self._first_pending_s > _FLUSH_AFTER_S
            )
        if due:
            self.flush()

    def flush(self) -> None:
        """Write the rows not yet on disk (merged with what other processes wrote meanwhile)."""
        with self._lock:
            if not self._pending or not self._writable:
                return
            rows = self._read()
            rows.update(self._pending)
            if len(rows) > MAX_ROWS:
                log.info(
                    "embedding cache %s is full (%d texts); new texts are not stored", self.path, MAX_ROWS
                )
                self._pending.clear()
                return
            texts = list(rows)
            tmp = self.path.with_name(f"{self.path.stem}.{os.getpid()}.{threading.get_ident()}.tmp.npz")
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                np.savez(
                    tmp, texts=np.asarray(texts, dtype=str), embeddings=np.stack([rows[t] for t in texts])
                )
                os.replace(tmp, self.path)
            except OSError as exc:
                self._writable = False
                log.info(
                    "embedding cache %s not written (%s): these texts are embedded at every start",
                    self.path,
                    exc,
                )
                try:
                    tmp.unlink(missing_ok=True)
                except OSError:
                    pass
            self._pending.clear()
