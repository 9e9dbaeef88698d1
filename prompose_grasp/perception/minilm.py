"""all-MiniLM-L6-v2 in numpy: the BERT encoder and its tokenizer, loaded from the local model folder.

Profiled on a cold `prompose-grasp estimate` (2 cores): importing sentence-transformers cost ~5 s on top of
torch's own ~2 s, and torch was imported for nothing but the text encoder (the embedded estimator's fit is
numpy + scipy). A prompt is a few phrases of a handful of tokens: a 6-layer, 384-wide BERT over them is a
few dozen small matrix products, milliseconds in numpy. So the model is spelled out here in numpy (~100
lines: embeddings, 6 x (self-attention, feed-forward, LayerNorm), then the attention-mask mean and L2
normalisation of `1_Pooling/config.json` / `modules.json`), its weights read from `model.safetensors` as
numpy arrays, and the tokenizer is the folder's own `tokenizer.json` through `tokenizers` (the Rust
WordPiece tokenizer sentence-transformers uses as well). Neither import loads torch.
tests/perception/test_text.py checks embeddings and token features against sentence-transformers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.minilm_config import BertConfig, read_config

__all__ = ["BertConfig", "NumpyBert", "load_minilm", "load_tokenizer", "read_config"]

#: Weights in the folder's file that the sentence embedding does not use: BERT's pooler (the [CLS] head,
#: unused by mean pooling) and the position-id buffer (positions are 0..L-1).
_UNUSED_KEYS = frozenset({"embeddings.position_ids", "pooler.dense.weight", "pooler.dense.bias"})


def _layer_norm(x: np.ndarray, w: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    mu = x.mean(axis=-1, keepdims=True)
    var = np.square(x - mu).mean(axis=-1, keepdims=True)
    return (x - mu) / np.sqrt(var + eps) * w + b


def _gelu(x: np.ndarray) -> np.ndarray:
    """The exact (erf) GELU of BERT's "gelu"."""
    from scipy.special import erf

    return 0.5 * x * (1.0 + erf(x / np.float32(np.sqrt(2.0))))


class NumpyBert:
    """A BERT encoder (no pooler) over float32 numpy weights named as in the Hugging Face checkpoint.

    Args:
        config: the model's sizes (`read_config`).
        weights: parameter name -> array, exactly the checkpoint's names less `_UNUSED_KEYS` (a missing or
            extra name, or a wrong shape, is an error: the strict load of a `torch.nn.Module`).
    """

    def __init__(self, config: BertConfig, weights: dict[str, np.ndarray]):
        self.config = config
        c, d = config, config.hidden_size
        expected = {
            "embeddings.word_embeddings.weight": (c.vocab_size, d),
            "embeddings.position_embeddings.weight": (c.max_position_embeddings, d),
            "embeddings.token_type_embeddings.weight": (c.type_vocab_size, d),
            "embeddings.LayerNorm.weight": (d,),
            "embeddings.LayerNorm.bias": (d,),
        }
        for i in range(c.num_hidden_layers):
            p = f"encoder.layer.{i}."
            for name in ("attention.self.query", "attention.self.key", "attention.self.value",
                         "attention.output.dense"):  # fmt: skip
                expected[p + name + ".weight"] = (d, d)
                expected[p + name + ".bias"] = (d,)
            expected[p + "intermediate.dense.weight"] = (c.intermediate_size, d)
            expected[p + "intermediate.dense.bias"] = (c.intermediate_size,)
            expected[p + "output.dense.weight"] = (d, c.intermediate_size)
            expected[p + "output.dense.bias"] = (d,)
            for norm in ("attention.output.LayerNorm", "output.LayerNorm"):
                expected[p + norm + ".weight"] = (d,)
                expected[p + norm + ".bias"] = (d,)
        given = {k: v for k, v in weights.items() if k not in _UNUSED_KEYS}
        missing, extra = sorted(set(expected) - set(given)), sorted(set(given) - set(expected))
        if missing or extra:
            raise InvalidInputError(
                f"BERT weights do not fit the config: missing {missing[:3]}, unexpected {extra[:3]}"
            )
        bad = [k for k, shape in expected.items() if given[k].shape != shape]
        if bad:
            raise InvalidInputError(
                f"BERT weight {bad[0]} has shape {given[bad[0]].shape}, expected {expected[bad[0]]}"
            )
        self.w = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in given.items()}
        # Linear layers compute x @ W.T + b: keep W.T contiguous once rather than at every product
        self.wt = {
            k: np.ascontiguousarray(v.T) for k, v in self.w.items() if v.ndim == 2 and "embeddings" not in k
        }

    def _linear(self, x: np.ndarray, name: str) -> np.ndarray:
        # one (N * L, D_in) x (D_in, D_out) product: a 3-D `x @ W` runs one small product per text instead
        w = self.wt[name + ".weight"]
        return (x.reshape(-1, x.shape[-1]) @ w + self.w[name + ".bias"]).reshape(*x.shape[:-1], w.shape[1])

    def __call__(self, input_ids: np.ndarray, attention_mask: np.ndarray) -> np.ndarray:
        """(N, L) int ids and (N, L) 0/1 mask -> (N, L, D) float32 last hidden states."""
        c, w = self.config, self.w
        n, length = input_ids.shape
        eps = c.layer_norm_eps
        x = (
            w["embeddings.word_embeddings.weight"][input_ids]
            + w["embeddings.position_embeddings.weight"][:length][None]
            + w["embeddings.token_type_embeddings.weight"][0]  # one segment: every token type is 0
        )
        x = _layer_norm(x, w["embeddings.LayerNorm.weight"], w["embeddings.LayerNorm.bias"], eps)
        heads, d = c.num_attention_heads, c.hidden_size
        dh = d // heads
        # padded keys get the most negative float32 before the softmax, as transformers' eager attention does
        key_bias = np.where(np.asarray(attention_mask, dtype=bool), 0.0, np.finfo(np.float32).min)
        key_bias = key_bias.astype(np.float32)[:, None, None, :]
        scale = np.float32(1.0 / np.sqrt(dh))
        for i in range(c.num_hidden_layers):
            p = f"encoder.layer.{i}."

            def split(t: np.ndarray) -> np.ndarray:  # (N, L, D) -> (N, heads, L, dh)
                return t.reshape(n, length, heads, dh).transpose(0, 2, 1, 3)

            q = split(self._linear(x, p + "attention.self.query"))
            k = split(self._linear(x, p + "attention.self.key"))
            v = split(self._linear(x, p + "attention.self.value"))
            scores = (q @ k.transpose(0, 1, 3, 2)) * scale + key_bias
            scores = np.exp(scores - scores.max(axis=-1, keepdims=True))
            attn = scores / scores.sum(axis=-1, keepdims=True)
            ctx = (attn @ v).transpose(0, 2, 1, 3).reshape(n, length, d)
            a = self._linear(ctx, p + "attention.output.dense") + x
            a = _layer_norm(
                a, w[p + "attention.output.LayerNorm.weight"], w[p + "attention.output.LayerNorm.bias"], eps
            )
            h = _gelu(self._linear(a, p + "intermediate.dense"))
            x = self._linear(h, p + "output.dense") + a
            x = _layer_norm(x, w[p + "output.LayerNorm.weight"], w[p + "output.LayerNorm.bias"], eps)
        return x.astype(np.float32, copy=False)


def load_minilm(folder: Path) -> NumpyBert:
    """The BERT of a sentence-transformers folder (`model.safetensors` read as numpy arrays), strict."""
    from safetensors.numpy import load_file

    weights = folder / "model.safetensors"
    if not weights.is_file():
        raise InvalidInputError(f"model folder {str(folder)!r} holds no model.safetensors")
    return NumpyBert(read_config(folder), load_file(str(weights)))


def load_tokenizer(folder: Path, max_length: int) -> Any:
    """The folder's WordPiece tokenizer (`tokenizer.json`): truncation at `max_length` tokens (special tokens
    included) and padding to the longest text of a batch, as sentence-transformers configures it."""
    from tokenizers import Tokenizer

    path = folder / "tokenizer.json"
    if not path.is_file():
        raise InvalidInputError(f"model folder {str(folder)!r} holds no tokenizer.json")
    tok = Tokenizer.from_file(str(path))
    tok.enable_truncation(max_length=max_length)
    tok.enable_padding(pad_id=0, pad_token="[PAD]")
    return tok
