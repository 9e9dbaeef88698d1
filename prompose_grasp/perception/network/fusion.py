"""The asymmetric cross-modal attention (ACA, paper section 3.4).

C_t = Proj_G(G_t^can) ⊕ Proj_G(G_O^can) ⊕ Proj_T(T_text) and
F_t = softmax(V_t W_Q (C_t W_K)^T / sqrt(d_k)) C_t W_V: the visual tokens are the only queries, so F_t has
exactly one row per visual token (the attention is anchored on what the camera sees; geometry and text are
only looked up). Proj_G is one projection shared by the observed-canonical and prior streams. A learnable type
embedding per stream (observation / prior / text) is added to the context so that attention can tell the two
geometry streams apart (they share Proj_G). Each layer is pre-norm cross-attention + feed-forward with
residuals (`CrossAttentionLayer`).

With `config.fusion = "symmetric"` (the ablation of paper Table 2) the visual tokens join the context and
every token attends to every other one (self-attention over all modalities); F_t is then all the tokens,
so what the camera sees no longer anchors the fused representation.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.layers import CrossAttentionLayer

__all__ = ["AsymmetricCrossModalAttention"]


class AsymmetricCrossModalAttention(nn.Module):
    """ACA: visual queries over projected canonical-geometry, prior and text tokens."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        d = config.latent_dim
        self.proj_geometry = nn.Linear(config.geometry_dim, d)
        self.proj_text = nn.Linear(config.text_dim, d)
        self.symmetric = config.fusion == "symmetric"
        self.type_embed = nn.Parameter(torch.zeros(3, d))
        nn.init.normal_(self.type_embed, std=0.02)
        self.layers = nn.ModuleList(
            [CrossAttentionLayer(d, config.num_heads, config.mlp_ratio) for _ in range(config.aca_layers)]
        )

    def forward(
        self,
        visual: Tensor,
        observed_canonical: Tensor,
        prior_canonical: Tensor,
        text: Tensor,
        text_valid: Tensor,
    ) -> dict[str, Tensor]:
        """
        Args:
            visual: (B, Nv, d) visual tokens V_t (the queries).
            observed_canonical: (B, Mo, geometry_dim) G_t^can.
            prior_canonical: (B, Mp, geometry_dim) G_O^can.
            text: (B, L, text_dim) frozen text token features.
            text_valid: (B, L) bool, False for padding tokens.
        Returns:
            `fused` (B, Nv, d) F_t; `attention` (B, Nv, Mo + Mp + L) the last layer's weights (head mean).
            Symmetric fusion: `fused` (B, Nv + Mo + Mp + L, d) and `attention` over all those tokens.
        """
        obs = self.proj_geometry(observed_canonical) + self.type_embed[0]
        prior = self.proj_geometry(prior_canonical) + self.type_embed[1]
        txt = self.proj_text(text) + self.type_embed[2]
        context = torch.cat([obs, prior, txt], dim=1)
        geo_valid = torch.ones(
            context.shape[0], obs.shape[1] + prior.shape[1], dtype=torch.bool, device=visual.device
        )
        valid = torch.cat([geo_valid, text_valid], dim=1)
        weights = visual.new_zeros(0)
        if self.symmetric:
            x = torch.cat([visual, context], dim=1)
            all_valid = torch.cat([torch.ones_like(valid[:, :1]).expand(-1, visual.shape[1]), valid], dim=1)
            for layer in self.layers:
                x, weights = layer(x, x, all_valid)
            return {"fused": x, "attention": weights}
        x = visual
        for layer in self.layers:
            x, weights = layer(x, context, valid)
        return {"fused": x, "attention": weights}
