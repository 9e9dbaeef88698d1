"""The decoupled pose heads (paper section 3.6).

- `RotationTranslationHead`: the refined rotation and translation tokens attend to the canonical prior's shape
  tokens S = Proj(G_O^can) (structure-aligned decoding), then MLP_R -> a 6-D rotation (the first two columns
  of R before Gram-Schmidt, Zhou et al. 2019) and MLP_T -> a translation offset.
- `ScaleHead`: the refined scale token alone (no prior: the scale comes from metric evidence only) ->
  a log-size offset.

Offsets are relative to the observation (see `model.decode_pose`), which keeps the regression targets of
order one at every distance and object size.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.layers import CrossAttentionLayer, mlp

__all__ = ["RotationTranslationHead", "ScaleHead"]

#: 6-D rotation of the identity (columns x and y of I): the bias the rotation output starts from.
_IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
#: Initial log offset of the size: size = |e| * exp(offset), and a cube's side is |e| / sqrt(3).
_LOG_INV_SQRT3 = -0.5493061443340549


def _small_init(layer: nn.Module, bias: tuple[float, ...] | float) -> None:
    # Small but non-zero weights: outputs start near the bias yet every input still changes them.
    assert isinstance(layer, nn.Linear)
    nn.init.normal_(layer.weight, std=1e-2)
    with torch.no_grad():
        layer.bias.copy_(torch.as_tensor(bias, dtype=layer.bias.dtype).expand_as(layer.bias))


class RotationTranslationHead(nn.Module):
    """(H_R, H_T) (B, n, d) each + prior tokens (B, Mp, geometry_dim) -> rot6d (B, n, 6), offset (B, n, 3)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        d = config.latent_dim
        self.proj_prior = nn.Linear(config.geometry_dim, d)
        self.layers = nn.ModuleList(
            [CrossAttentionLayer(d, config.num_heads, config.mlp_ratio) for _ in range(config.head_layers)]
        )
        self.mlp_rotation = mlp(d, d, 6)
        self.mlp_translation = mlp(d, d, 3)
        _small_init(self.mlp_rotation[-1], _IDENTITY_6D)
        _small_init(self.mlp_translation[-1], 0.0)

    def forward(self, h_rotation: Tensor, h_translation: Tensor, prior_tokens: Tensor) -> dict[str, Tensor]:
        B, n, d = h_rotation.shape
        shape = self.proj_prior(prior_tokens)
        x = torch.stack([h_rotation, h_translation], dim=2).reshape(B, 2 * n, d)
        for layer in self.layers:
            x, _ = layer(x, shape)
        x = x.reshape(B, n, 2, d)
        return {
            "rot6d": self.mlp_rotation(x[:, :, 0]),
            "translation_offset": self.mlp_translation(x[:, :, 1]),
        }


class ScaleHead(nn.Module):
    """H_S (B, n, d) -> log-size offset (B, n, 3); never sees the prior."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        d = config.latent_dim
        self.norm = nn.LayerNorm(d)
        self.mlp = mlp(d, d * config.mlp_ratio, 3)
        _small_init(self.mlp[-1], _LOG_INV_SQRT3)

    def forward(self, h_scale: Tensor) -> dict[str, Tensor]:
        return {"log_size_offset": self.mlp(self.norm(h_scale))}
