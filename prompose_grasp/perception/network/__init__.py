"""The learned ProM-Pose network (paper section 3) in plain PyTorch: one `nn.Module` per concern.

- `config`: `NetworkConfig`, variants `paper` (section 4.1 sizes) and `tiny` (2-core CPU), `network_config`.
- `visual`: phi_V, `SmallVisualEncoder` (default, trained here), `DinoV2VisualEncoder` (frozen, local
  weights).
- `geometry`: phi_G, a Point-Transformer-v2-style encoder shared by all three point streams.
- `fusion`: the asymmetric cross-modal attention (visual tokens query geometry + prior + text tokens).
- `pose_tokens`: geometry-conditioned learnable queries -> Z_R, Z_T, Z_S.
- `temporal`: phi_temp over a window of n frames with learnable positional encodings.
- `heads`: rotation-translation head (cross-attends the prior tokens), scale head (temporal features only).
- `model`: `ProMPoseNet`, the whole network; `losses`: L_pose, L_temp, L_geo; `data`: dataset -> batches;
  `checkpoint`: `save_checkpoint`, `load_estimator(weights, device)` (strict).

The text encoder phi_T is the frozen `prompose_grasp.perception.text` encoder; the network takes its token
features. Training: `prompose_grasp.perception.train`. See docs/network.md.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.network.checkpoint import SHIPPED_WEIGHTS, load_estimator, save_checkpoint
    from prompose_grasp.perception.network.config import ABLATIONS, CONFIGS, NetworkConfig, network_config
    from prompose_grasp.perception.network.data import (
        AugmentConfig,
        NetworkBatch,
        ObjectTrack,
        collate,
        load_tracks,
        make_windows,
    )
    from prompose_grasp.perception.network.losses import LossConfig, pose_loss, symmetric_rotation_error
    from prompose_grasp.perception.network.model import ProMPoseNet

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.network.checkpoint": (
            "SHIPPED_WEIGHTS",
            "load_estimator",
            "save_checkpoint",
        ),
        "prompose_grasp.perception.network.config": (
            "ABLATIONS",
            "CONFIGS",
            "NetworkConfig",
            "network_config",
        ),
        "prompose_grasp.perception.network.data": (
            "AugmentConfig",
            "NetworkBatch",
            "ObjectTrack",
            "collate",
            "load_tracks",
            "make_windows",
        ),
        "prompose_grasp.perception.network.losses": (
            "LossConfig",
            "pose_loss",
            "symmetric_rotation_error",
        ),
        "prompose_grasp.perception.network.model": ("ProMPoseNet",),
    },
    submodules=(
        "checkpoint",
        "config",
        "data",
        "fusion",
        "geometry",
        "heads",
        "layers",
        "losses",
        "model",
        "pose_head",
        "pose_tokens",
        "rotations",
        "temporal",
        "visual",
    ),
)

__all__ = [
    "ABLATIONS",
    "CONFIGS",
    "SHIPPED_WEIGHTS",
    "AugmentConfig",
    "LossConfig",
    "NetworkBatch",
    "NetworkConfig",
    "ObjectTrack",
    "ProMPoseNet",
    "collate",
    "load_estimator",
    "load_tracks",
    "make_windows",
    "network_config",
    "pose_loss",
    "save_checkpoint",
    "symmetric_rotation_error",
]
