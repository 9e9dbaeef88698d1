"""`NetworkConfig`: every size of the ProM-Pose network, and the named variants `paper` and `tiny`.

The `paper` variant has the sizes of section 4.1 (512-d latent, 8 heads, a window of n = 16 frames, a Point
Transformer v2 geometry encoder of hidden width 256, 2048 observed and 5000 prior points). The `tiny` variant
keeps every module and only shrinks the widths and counts, so that it trains on a 2-core CPU in minutes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from prompose_grasp.errors import InvalidInputError, UnknownNameError

__all__ = [
    "ABLATIONS",
    "CONFIGS",
    "FUSIONS",
    "PRIOR_SOURCES",
    "VISUAL_BACKBONES",
    "NetworkConfig",
    "network_config",
]

#: Visual encoders phi_V: `small` is trained by this project; `dinov2` is the paper's frozen DINOv2 adapter.
VISUAL_BACKBONES = ("small", "dinov2")
#: Where the prior points come from: `generated` (the text-conditioned prior fed in, the paper's method) or
#: `generic` (a fixed unit-cube surface for every object: the "without generative prior" ablation).
PRIOR_SOURCES = ("generated", "generic")
#: Cross-modal fusion: `asymmetric` (ACA, visual tokens are the only queries) or `symmetric` (every token of
#: every modality attends to all of them: the "symmetric fusion" ablation of paper Table 2).
FUSIONS = ("asymmetric", "symmetric")
#: The ablations of paper Table 2 as config changes (`without L_geo` is a loss weight, see `LossConfig`).
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {},
    "no_generative_prior": {"prior": "generic"},
    "symmetric_fusion": {"fusion": "symmetric"},
    "no_decoupling": {"decoupled": False},
    "no_temporal": {"temporal": False},
}


@dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the ProM-Pose network (all counts are positive integers).

    Attributes:
        latent_dim: width d of the fused tokens (ACA, pose tokens, temporal transformer, heads).
        num_heads: attention heads in the ACA, pose-token, temporal and head attentions; divides latent_dim.
        window: temporal window n (frames the temporal transformer sees at once).
        visual_backbone: one of `VISUAL_BACKBONES`.
        crop_px: side of the square object-centric RGB crop fed to phi_V [px].
        visual_channels: channels of the first convolution of the small visual encoder (doubled per stage).
        visual_stride: total downsampling of the small encoder (a power of two >= 4); (crop/stride)^2 tokens.
        visual_layers: transformer layers on top of the small encoder's patch tokens.
        dinov2_dir: local folder of a DINOv2 model (`save_pretrained` layout) for the `dinov2` backbone.
        dinov2_dim: hidden width of that DINOv2 model (1536 for ViT-g/14), so the projection can be built.
        text_dim: width of the frozen text encoder's token features (384 MiniLM, 768 BERT-Base).
        observed_points: points of the observed cloud after farthest point sampling (paper: 2048).
        prior_points: points of the canonical prior (paper: 5000).
        geometry_dim: hidden width of the Point Transformer geometry encoder phi_G (paper: 256).
        geometry_strides: FPS downsampling factor of each encoder stage; tokens = points / prod(strides).
        geometry_blocks: grouped-vector-attention blocks per stage.
        geometry_neighbors: k of the kNN neighbourhoods.
        geometry_groups: groups of the grouped vector attention; divides geometry_dim.
        aca_layers: stacked asymmetric cross-modal attention layers.
        pose_queries: learnable queries per pose component (R, T, S); their outputs are averaged.
        temporal_layers: layers of the temporal transformer phi_temp.
        head_layers: cross-attention layers of the rotation-translation head over the prior tokens.
        mlp_ratio: hidden width of every feed-forward block, as a multiple of its input width.
        prior: one of `PRIOR_SOURCES` (ablation switch; the method is `generated`).
        fusion: one of `FUSIONS` (ablation switch; the method is `asymmetric`).
        decoupled: metric-canonical decoupling: the ACA sees the observation normalised into the unit box
            while g_met carries the metric scale (False: the ACA sees the metric cloud; ablation switch).
        temporal: the temporal transformer phi_temp (False: each frame is decoded on its own; ablation).
    """

    latent_dim: int = 512
    num_heads: int = 8
    window: int = 16
    visual_backbone: str = "small"
    crop_px: int = 224
    visual_channels: int = 64
    visual_stride: int = 16
    visual_layers: int = 2
    dinov2_dir: str = ""
    dinov2_dim: int = 1536
    text_dim: int = 384
    observed_points: int = 2048
    prior_points: int = 5000
    geometry_dim: int = 256
    geometry_strides: tuple[int, ...] = (4, 4)
    geometry_blocks: int = 2
    geometry_neighbors: int = 16
    geometry_groups: int = 8
    aca_layers: int = 2
    pose_queries: int = 1
    temporal_layers: int = 4
    head_layers: int = 2
    mlp_ratio: int = 4
    prior: str = "generated"
    fusion: str = "asymmetric"
    decoupled: bool = True
    temporal: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "geometry_strides", tuple(int(s) for s in self.geometry_strides))
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("visual_backbone", "dinov2_dir", "prior", "fusion"):
                if not isinstance(v, str):
                    raise InvalidInputError(f"NetworkConfig.{f.name} must be a str, got {v!r}")
                continue
            if f.name in ("decoupled", "temporal"):
                if not isinstance(v, bool):
                    raise InvalidInputError(f"NetworkConfig.{f.name} must be a bool, got {v!r}")
                continue
            if f.name == "geometry_strides":
                if not v or any(s < 1 for s in v):
                    raise InvalidInputError(f"geometry_strides must be >= 1 each, at least one; got {v!r}")
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidInputError(f"NetworkConfig.{f.name} must be a positive int, got {v!r}")
        if self.visual_backbone not in VISUAL_BACKBONES:
            raise UnknownNameError("visual backbone", self.visual_backbone, VISUAL_BACKBONES)
        if self.prior not in PRIOR_SOURCES:
            raise UnknownNameError("prior source", self.prior, PRIOR_SOURCES)
        if self.fusion not in FUSIONS:
            raise UnknownNameError("fusion", self.fusion, FUSIONS)
        if self.latent_dim % self.num_heads:
            raise InvalidInputError(
                f"latent_dim {self.latent_dim} must be divisible by num_heads {self.num_heads}"
            )
        if self.geometry_dim % self.geometry_groups:
            raise InvalidInputError(
                f"geometry_dim {self.geometry_dim} must be divisible by "
                f"geometry_groups {self.geometry_groups}"
            )
        s = self.visual_stride
        if s < 4 or s & (s - 1):
            raise InvalidInputError(f"visual_stride must be a power of two >= 4, got {s}")
        if self.crop_px % s:
            raise InvalidInputError(f"crop_px {self.crop_px} must be a multiple of visual_stride {s}")
        total = 1
        for st in self.geometry_strides:
            total *= st
        if self.observed_points // total < 1 or self.prior_points // total < 1:
            raise InvalidInputError(
                f"geometry_strides {self.geometry_strides} downsample {self.observed_points} observed / "
                f"{self.prior_points} prior points to nothing; use fewer or smaller strides"
            )

    @property
    def visual_tokens(self) -> int:
        """Visual tokens per frame for the small encoder ((crop_px / visual_stride)^2)."""
        return (self.crop_px // self.visual_stride) ** 2

    def to_dict(self) -> dict[str, Any]:
        """JSON/checkpoint-ready dict (tuples become lists)."""
        d = asdict(self)
        d["geometry_strides"] = list(self.geometry_strides)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetworkConfig:
        """Inverse of `to_dict`; unknown keys raise `UnknownNameError` listing the fields."""
        names = [f.name for f in fields(cls)]
        for k in d:
            if k not in names:
                raise UnknownNameError("NetworkConfig field", k, names)
        kwargs: dict[str, Any] = {k: (tuple(v) if k == "geometry_strides" else v) for k, v in d.items()}
        return cls(**kwargs)

    def with_(self, **changes: Any) -> NetworkConfig:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


#: Named variants. `paper`: section 4.1. `tiny`: the same modules, small enough for a 2-core CPU.
CONFIGS: dict[str, NetworkConfig] = {
    "paper": NetworkConfig(),
    "tiny": NetworkConfig(
        latent_dim=64,
        num_heads=4,
        window=4,
        crop_px=32,
        visual_channels=16,
        visual_stride=8,
        visual_layers=1,
        observed_points=256,
        prior_points=512,
        geometry_dim=32,
        geometry_strides=(4, 2),
        geometry_blocks=1,
        geometry_neighbors=8,
        geometry_groups=4,
        aca_layers=1,
        temporal_layers=1,
        head_layers=1,
        mlp_ratio=2,
    ),
}


def network_config(name: str, ablation: str = "full", **overrides: Any) -> NetworkConfig:
    """The named variant (`paper`, `tiny`), with one of `ABLATIONS` applied and some fields changed."""
    try:
        base = CONFIGS[name]
    except KeyError:
        raise UnknownNameError("network config", name, CONFIGS) from None
    if ablation not in ABLATIONS:
        raise UnknownNameError("ablation", ablation, ABLATIONS)
    changes = {**ABLATIONS[ablation], **overrides}
    return base.with_(**changes) if changes else base
