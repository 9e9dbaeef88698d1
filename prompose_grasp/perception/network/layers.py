"""Small building blocks shared by the network's modules: a feed-forward block and a pre-norm cross-attention
layer. Each is one `nn.Module`; nothing here seeds, allocates on a device or writes files."""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["CrossAttentionLayer", "FeedForward", "mlp"]


def mlp(in_dim: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    """Linear -> GELU -> Linear."""
    return nn.Sequential(nn.Linear(in_dim, hidden_dim), nn.GELU(), nn.Linear(hidden_dim, out_dim))


class FeedForward(nn.Module):
    """Pre-norm residual feed-forward block: x + MLP(LN(x)). Shapes (..., dim) -> (..., dim)."""

    def __init__(self, dim: int, mlp_ratio: int):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.mlp = mlp(dim, dim * mlp_ratio, dim)

    def forward(self, x: Tensor) -> Tensor:
        return x + self.mlp(self.norm(x))


class CrossAttentionLayer(nn.Module):
    """Pre-norm cross-attention with a residual, then a feed-forward block.

    `forward(queries (B, Q, d), context (B, K, d), context_valid (B, K) bool | None)` returns
    `(out (B, Q, d), weights (B, Q, K))`, weights averaged over heads. The output has one row per query:
    the queries decide where to look, the context only supplies what is found there.
    """

    def __init__(self, dim: int, num_heads: int, mlp_ratio: int):
        super().__init__()
        self.norm_q = nn.LayerNorm(dim)
        self.norm_kv = nn.LayerNorm(dim)
        self.attn = nn.MultiheadAttention(dim, num_heads, dropout=0.0, batch_first=True)
        self.ffn = FeedForward(dim, mlp_ratio)

    def forward(
        self, queries: Tensor, context: Tensor, context_valid: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        q = self.norm_q(queries)
        kv = self.norm_kv(context)
        # MultiheadAttention masks where key_padding_mask is True, i.e. the invalid keys.
        pad = None if context_valid is None else ~context_valid
        out, weights = self.attn(
            q, kv, kv, key_padding_mask=pad, need_weights=True, average_attn_weights=True
        )
        x = queries + out
        return self.ffn(x), weights


def batched_gather(x: Tensor, idx: Tensor) -> Tensor:
    """Rows of `x` (B, N, C) picked by `idx` (B, ...) long -> (B, ..., C)."""
    B = x.shape[0]
    flat = idx.reshape(B, -1)
    out = torch.gather(x, 1, flat.unsqueeze(-1).expand(-1, -1, x.shape[-1]))
    return out.reshape(*idx.shape, x.shape[-1])
