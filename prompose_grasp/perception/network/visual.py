"""phi_V: visual tokens of the object-centric RGB crop.

Two encoders with one interface, `forward(images (B, 3, H, W) float in [0, 1]) -> {"tokens": (B, Nv, d)}`:

- `SmallVisualEncoder`, the default, trained with the rest of the network: a strided convolution stack (each
  stage halves the resolution and doubles the channels) to a (H / stride) x (W / stride) grid, a 1x1
  projection to d, learnable 2-D position embeddings and `visual_layers` transformer layers.
- `DinoV2VisualEncoder`, the paper's adapter (section 4.1): a frozen DINOv2 from a local folder through
  `transformers` (extra `hub`); its last-layer patch tokens (CLS dropped) are projected to d by a trained
  linear layer. Only the projection is trained or stored in checkpoints (see `checkpoint.py`).

Both normalise with the ImageNet mean and standard deviation, as DINOv2 was trained.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.network.config import NetworkConfig

__all__ = ["DinoV2VisualEncoder", "SmallVisualEncoder", "build_visual_encoder"]

_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


class _ImageNorm(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        # Buffers, not parameters: constants that move with .to(device) but are never trained.
        self.register_buffer("mean", torch.tensor(_IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(_IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    mean: Tensor
    std: Tensor

    def forward(self, images: Tensor) -> Tensor:
        return (images - self.mean) / self.std


class SmallVisualEncoder(nn.Module):
    """The embedded visual encoder: (B, 3, crop_px, crop_px) in [0, 1] -> tokens (B, (crop/stride)^2, d)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        self.norm_in = _ImageNorm()
        stages: list[nn.Module] = []
        c_in, c = 3, config.visual_channels
        for _ in range(config.visual_stride.bit_length() - 1):  # log2(stride) stride-2 stages
            stages += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.GroupNorm(min(8, c), c), nn.GELU()]
            c_in, c = c, c * 2
        self.convs = nn.Sequential(*stages)
        self.proj = nn.Conv2d(c_in, config.latent_dim, 1)
        self.pos = nn.Parameter(torch.zeros(1, config.visual_tokens, config.latent_dim))
        nn.init.normal_(self.pos, std=0.02)
        layer = nn.TransformerEncoderLayer(
            config.latent_dim,
            config.num_heads,
            config.latent_dim * config.mlp_ratio,
            dropout=0.0,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.blocks = nn.TransformerEncoder(layer, config.visual_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(config.latent_dim)
        self.crop_px = config.crop_px

    def forward(self, images: Tensor) -> dict[str, Tensor]:
        if images.shape[-2:] != (self.crop_px, self.crop_px):
            raise InvalidInputError(
                f"crops must be {self.crop_px}x{self.crop_px} px for this config, "
                f"got {tuple(images.shape[-2:])}"
            )
        x = self.proj(self.convs(self.norm_in(images)))  # (B, d, h, w)
        x = x.flatten(2).transpose(1, 2) + self.pos
        return {"tokens": self.norm(self.blocks(x))}


class DinoV2VisualEncoder(nn.Module):
    """Frozen DINOv2 (local weights) + a trained linear projection: (B, 3, H, W) -> tokens (B, Nv, d).

    `H` and `W` must be multiples of the model's patch size (14 for the released models); the paper uses
    518 x 518 crops (37 x 37 tokens).
    """

    def __init__(self, config: NetworkConfig, weights_dir: str | Path | None = None):
        super().__init__()
        transformers = require("transformers", extra="hub")
        path = Path(weights_dir or config.dinov2_dir)
        if not str(weights_dir or config.dinov2_dir) or not (path / "config.json").is_file():
            raise InvalidInputError(
                f"the dinov2 visual backbone needs a local DINOv2 folder with config.json (save_pretrained "
                f"layout); got {str(path)!r}. Set NetworkConfig.dinov2_dir or use visual_backbone='small'"
            )
        self.backbone = transformers.Dinov2Model.from_pretrained(str(path), local_files_only=True)
        self.backbone.requires_grad_(False)
        self.backbone.eval()
        hidden = int(self.backbone.config.hidden_size)
        if hidden != config.dinov2_dim:
            raise InvalidInputError(
                f"DINOv2 at {str(path)!r} has hidden size {hidden} but NetworkConfig.dinov2_dim is "
                f"{config.dinov2_dim}; set dinov2_dim={hidden}"
            )
        self.patch = int(self.backbone.config.patch_size)
        self.norm_in = _ImageNorm()
        self.proj = nn.Linear(hidden, config.latent_dim)
        self.norm = nn.LayerNorm(config.latent_dim)

    def train(self, mode: bool = True) -> DinoV2VisualEncoder:
        super().train(mode)
        self.backbone.eval()  # frozen: its dropout / norm statistics never switch to training behaviour
        return self

    def forward(self, images: Tensor) -> dict[str, Tensor]:
        H, W = images.shape[-2:]
        if H % self.patch or W % self.patch:
            raise InvalidInputError(f"crop size {H}x{W} must be a multiple of the DINOv2 patch {self.patch}")
        with torch.no_grad():
            hidden = self.backbone(pixel_values=self.norm_in(images)).last_hidden_state
        return {"tokens": self.norm(self.proj(hidden[:, 1:]))}


def build_visual_encoder(config: NetworkConfig, dinov2_dir: str | Path | None = None) -> nn.Module:
    """The phi_V the config names (`small` or `dinov2`; `dinov2_dir` overrides `config.dinov2_dir`)."""
    if config.visual_backbone == "dinov2":
        return DinoV2VisualEncoder(config, dinov2_dir)
    return SmallVisualEncoder(config)
