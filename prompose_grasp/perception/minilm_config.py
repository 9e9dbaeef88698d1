"""The configuration of a sentence-transformers BERT folder, read without torch (`perception.minilm` runs it).

`MiniLMTextEncoder` reads it when made, to know its width and truncation length, and loads torch and the
weights only when a text needs them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from prompose_grasp.errors import InvalidInputError

__all__ = ["BertConfig", "read_config"]


@dataclass(frozen=True)
class BertConfig:
    """The fields of a BERT `config.json` this encoder reads."""

    vocab_size: int
    hidden_size: int
    num_hidden_layers: int
    num_attention_heads: int
    intermediate_size: int
    max_position_embeddings: int
    type_vocab_size: int
    layer_norm_eps: float
    max_seq_length: int  # sentence-transformers' truncation length (`sentence_bert_config.json`)


def read_config(folder: Path) -> BertConfig:
    """The model's configuration, read from `config.json` (+ `sentence_bert_config.json`,
    `1_Pooling/config.json`) without loading any weight.

    Raises:
        InvalidInputError: a missing or unreadable file, a model that is not BERT with GELU, or pooling
            other than the attention-mask mean.
    """
    try:
        raw = json.loads((folder / "config.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"model folder {str(folder)!r}: config.json unreadable ({exc})") from None
    if raw.get("model_type") != "bert" or raw.get("hidden_act", "gelu") != "gelu":
        raise InvalidInputError(
            f"model folder {str(folder)!r} holds a {raw.get('model_type')!r} model with "
            f"{raw.get('hidden_act')!r}; this encoder runs BERT with GELU (e.g. all-MiniLM-L6-v2)"
        )
    pooling = folder / "1_Pooling" / "config.json"
    if pooling.is_file():
        pool = json.loads(pooling.read_text(encoding="utf-8"))
        others = [
            k
            for k, v in pool.items()
            if k.startswith("pooling_mode") and v and k != "pooling_mode_mean_tokens"
        ]
        if not pool.get("pooling_mode_mean_tokens", False) or others:
            raise InvalidInputError(
                f"model folder {str(folder)!r} pools with {others or 'no mean'}; this encoder takes the "
                "attention-mask mean of the tokens"
            )
    st_config = folder / "sentence_bert_config.json"
    max_seq = int(raw["max_position_embeddings"])
    if st_config.is_file():
        max_seq = int(json.loads(st_config.read_text(encoding="utf-8")).get("max_seq_length") or max_seq)
    try:
        return BertConfig(
            vocab_size=int(raw["vocab_size"]),
            hidden_size=int(raw["hidden_size"]),
            num_hidden_layers=int(raw["num_hidden_layers"]),
            num_attention_heads=int(raw["num_attention_heads"]),
            intermediate_size=int(raw["intermediate_size"]),
            max_position_embeddings=int(raw["max_position_embeddings"]),
            type_vocab_size=int(raw.get("type_vocab_size", 2)),
            layer_norm_eps=float(raw.get("layer_norm_eps", 1e-12)),
            max_seq_length=min(max_seq, int(raw["max_position_embeddings"])),
        )
    except KeyError as exc:
        raise InvalidInputError(f"model folder {str(folder)!r}: config.json lacks {exc}") from None
