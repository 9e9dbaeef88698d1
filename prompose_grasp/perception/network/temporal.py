"""phi_temp: the temporal transformer over a window of n frames (paper section 3.6).

Each frame contributes its three pose tokens Z_t = Z_R ⊕ Z_T ⊕ Z_S as three tokens (rather than one
concatenated vector) so that the decoupled heads can read the refined rotation, translation and scale tokens
separately. Learnable positional encodings P_1..n (one per frame slot) and a learnable type embedding per
component are added; a pre-norm transformer encoder attends over all 3n tokens of the window. Frames marked
invalid (padding at a sequence start, frames with no points) are masked out as keys.

With `config.temporal = False` (the "without temporal module" ablation) the same encoder runs on each frame's
three tokens alone: the capacity stays, only the attention across frames (and the frame positions) go.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.network.config import NetworkConfig

__all__ = ["TemporalTransformer"]


class TemporalTransformer(nn.Module):
    """(B, n, 3, d) pose tokens + (B, n) frame validity -> refined features H (B, n, 3, d), n <= window."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        d = config.latent_dim
        self.window = config.window
        self.across_frames = config.temporal
        self.positions = nn.Parameter(torch.zeros(config.window, d))
        self.types = nn.Parameter(torch.zeros(3, d))
        nn.init.normal_(self.positions, std=0.02)
        nn.init.normal_(self.types, std=0.02)
        layer = nn.TransformerEncoderLayer(
            d,
            config.num_heads,
            d * config.mlp_ratio,
            dropout=0.0,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.encoder = nn.TransformerEncoder(layer, config.temporal_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(d)

    def forward(self, tokens: Tensor, frame_valid: Tensor) -> dict[str, Tensor]:
        B, n, three, d = tokens.shape
        if n > self.window or three != 3:
            raise InvalidInputError(
                f"pose tokens must be (B, n <= {self.window}, 3, d), got {tuple(tokens.shape)}"
            )
        if not self.across_frames:
            h = self.encoder((tokens + self.types[None, :, :]).reshape(B * n, 3, d))
            return {"features": self.norm(h).reshape(B, n, 3, d)}
        x = tokens + self.positions[:n, None, :] + self.types[None, :, :]
        pad = (~frame_valid).repeat_interleave(3, dim=1)  # (B, 3n), True = ignore
        h = self.encoder(x.reshape(B, 3 * n, d), src_key_padding_mask=pad)
        return {"features": self.norm(h).reshape(B, n, 3, d)}
