"""all-MiniLM-L6-v2 in plain torch: the BERT encoder and its tokenizer, loaded from the local model folder.

sentence-transformers computes the same embeddings, but importing it (it imports `transformers` and its
model registry) cost ~5 s on top of torch's own ~1.8 s on a 2-core machine: most of a cold `prompose-grasp
estimate` call. The model itself is a 6-layer BERT (docs: the folder's `config.json`) with mean pooling
over the attention mask and L2 normalisation (`1_Pooling/config.json`, `modules.json`), which this module
spells out in ~100 lines; the tokenizer is the folder's own `tokenizer.json` through `tokenizers` (the Rust
WordPiece tokenizer that sentence-transformers uses as well). tests/perception/test_text.py checks the
embeddings and token features against sentence-transformers on the same folder.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
from torch import nn

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.minilm_config import BertConfig, read_config

__all__ = ["BertConfig", "BertModel", "load_minilm", "load_tokenizer", "read_config"]

#: Weights in the folder's file that the sentence embedding does not use: BERT's pooler (the [CLS] head,
#: unused by mean pooling) and the position-id buffer (recomputed here).
_UNUSED_KEYS = ("embeddings.position_ids", "pooler.dense.weight", "pooler.dense.bias")


class _Embeddings(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.word_embeddings = nn.Embedding(c.vocab_size, c.hidden_size, padding_idx=0)
        self.position_embeddings = nn.Embedding(c.max_position_embeddings, c.hidden_size)
        self.token_type_embeddings = nn.Embedding(c.type_vocab_size, c.hidden_size)
        self.LayerNorm = nn.LayerNorm(c.hidden_size, eps=c.layer_norm_eps)

    def forward(self, input_ids: torch.Tensor) -> torch.Tensor:
        positions = torch.arange(input_ids.shape[1], device=input_ids.device)
        x = self.word_embeddings(input_ids) + self.position_embeddings(positions)[None]
        x = x + self.token_type_embeddings.weight[0]  # one segment: every token type is 0
        return self.LayerNorm(x)


class _SelfAttention(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.heads = c.num_attention_heads
        self.query = nn.Linear(c.hidden_size, c.hidden_size)
        self.key = nn.Linear(c.hidden_size, c.hidden_size)
        self.value = nn.Linear(c.hidden_size, c.hidden_size)

    def forward(self, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        n, length, d = x.shape

        def split(t: torch.Tensor) -> torch.Tensor:  # (N, L, D) -> (N, heads, L, D / heads)
            return t.view(n, length, self.heads, d // self.heads).transpose(1, 2)

        q, k, v = split(self.query(x)), split(self.key(x)), split(self.value(x))
        scores = (q @ k.transpose(-1, -2)) / math.sqrt(d // self.heads)
        scores = scores.masked_fill(~keep[:, None, None, :], torch.finfo(scores.dtype).min)
        out = torch.softmax(scores, dim=-1) @ v
        return out.transpose(1, 2).reshape(n, length, d)


class _DenseNorm(nn.Module):
    """BERT's `output` blocks: dense, then LayerNorm of the sum with the block's input."""

    def __init__(self, d_in: int, c: BertConfig):
        super().__init__()
        self.dense = nn.Linear(d_in, c.hidden_size)
        self.LayerNorm = nn.LayerNorm(c.hidden_size, eps=c.layer_norm_eps)

    def forward(self, h: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        return self.LayerNorm(self.dense(h) + residual)


class _Attention(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.self = _SelfAttention(c)
        self.output = _DenseNorm(c.hidden_size, c)

    def forward(self, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        return self.output(self.self(x, keep), x)


class _Intermediate(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.dense = nn.Linear(c.hidden_size, c.intermediate_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.gelu(self.dense(x))  # the exact (erf) GELU of BERT's "gelu"


class _Layer(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.attention = _Attention(c)
        self.intermediate = _Intermediate(c)
        self.output = _DenseNorm(c.intermediate_size, c)

    def forward(self, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        a = self.attention(x, keep)
        return self.output(self.intermediate(a), a)


class _Encoder(nn.Module):
    def __init__(self, c: BertConfig):
        super().__init__()
        self.layer = nn.ModuleList(_Layer(c) for _ in range(c.num_hidden_layers))


class BertModel(nn.Module):
    """A BERT encoder (no pooler): token ids -> last hidden states. Parameter names match the Hugging Face
    checkpoint, so its `model.safetensors` loads with `strict=True` (less `_UNUSED_KEYS`)."""

    def __init__(self, config: BertConfig):
        super().__init__()
        self.config = config
        self.embeddings = _Embeddings(config)
        self.encoder = _Encoder(config)

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        """(N, L) int64 ids and (N, L) 0/1 mask -> (N, L, D) float32 last hidden states."""
        keep = attention_mask.bool()
        x = self.embeddings(input_ids)
        for layer in self.encoder.layer:
            x = layer(x, keep)
        return x


def load_minilm(folder: Path, device: str = "cpu") -> BertModel:
    """The BERT of a sentence-transformers folder (`model.safetensors`), strict, in eval mode on `device`."""
    from safetensors.torch import load_file

    weights = folder / "model.safetensors"
    if not weights.is_file():
        raise InvalidInputError(f"model folder {str(folder)!r} holds no model.safetensors")
    state = load_file(str(weights))
    for key in _UNUSED_KEYS:
        state.pop(key, None)
    model = BertModel(read_config(folder))
    model.load_state_dict(state, strict=True)
    return model.eval().to(device)


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
