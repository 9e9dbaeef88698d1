"""Pose-token extraction (paper section 3.5): geometry-conditioned learnable queries read the fused tokens.

Q~_R = Q_R + MLP_R(d_t), Q~_T = Q_T + MLP_T(d_t ⊕ g_met), Q~_S = Q_S + MLP_S(d_t ⊕ g_met), and
Z_* = Attn(Q~_*, F_t, F_t). d_t is the robust descriptor (centroid ⊕ vec(PCA axes) ⊕ extents, 15 values,
metres; `geometry.pointcloud.robust_descriptor`), g_met the mean-pooled metric geometry tokens. Rotation sees
only d_t (no metric bias); translation and scale also see g_met. Each component has its own cross-attention
layer and `pose_queries` queries, whose outputs are averaged into one token.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.layers import CrossAttentionLayer, mlp

__all__ = ["DESCRIPTOR_DIM", "PoseTokenExtractor"]

#: Width of d_t: centroid (3) ⊕ vec(U) (9) ⊕ extents (3).
DESCRIPTOR_DIM = 15


class PoseTokenExtractor(nn.Module):
    """(F_t, d_t, g_met) -> pose tokens Z_R, Z_T, Z_S, each (B, d)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        d = config.latent_dim
        self.queries = nn.Parameter(torch.zeros(3, config.pose_queries, d))
        nn.init.normal_(self.queries, std=0.02)
        self.mlp_rotation = mlp(DESCRIPTOR_DIM, d, d)
        self.mlp_translation = mlp(DESCRIPTOR_DIM + config.geometry_dim, d, d)
        self.mlp_scale = mlp(DESCRIPTOR_DIM + config.geometry_dim, d, d)
        self.attn = nn.ModuleList(
            [CrossAttentionLayer(d, config.num_heads, config.mlp_ratio) for _ in range(3)]
        )

    def forward(self, fused: Tensor, descriptor: Tensor, metric_global: Tensor) -> dict[str, Tensor]:
        """fused (B, Nv, d) F_t; descriptor (B, 15) d_t [m]; metric_global (B, geometry_dim) g_met.

        Returns `rotation`, `translation`, `scale`: (B, d) tokens Z_R, Z_T, Z_S.
        """
        d_ts = torch.cat([descriptor, metric_global], dim=-1)
        shifts = (self.mlp_rotation(descriptor), self.mlp_translation(d_ts), self.mlp_scale(d_ts))
        out = {}
        for i, (name, shift) in enumerate(zip(("rotation", "translation", "scale"), shifts)):
            q = self.queries[i].unsqueeze(0) + shift.unsqueeze(1)  # (B, q, d)
            z, _ = self.attn[i](q, fused)
            out[name] = z.mean(dim=1)
        return out
