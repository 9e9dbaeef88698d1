"""`ProMPoseNet`: the whole network of paper section 3 (Algorithm 1) as one `nn.Module`.

    T_text (frozen, precomputed) ─────────────────────────────┐
    prior points ──phi_G──> G_O^can ───────────────┐          │
    observed points ──Normalize──phi_G──> G_t^can ─┤          │
                                                   ACA(Q = phi_V(crop)) ──> F_t
    observed points ──phi_G──> G_t^met ──mean──> g_met          │
    d_t ────────────────────────────> PoseTokenExtract(F_t, d_t, g_met) ──> Z_t = Z_R ⊕ Z_T ⊕ Z_S
    Z_1..n + P_1..n ──phi_temp──> H_1..n ──> RT head (x-attn to G_O^can) -> R, t;  scale head -> size

phi_G is a single `GeometryEncoder` used for all three point streams (weight sharing by construction).
Outputs are metric: t = c_t + |e_t| * offset and size = |e_t| * exp(log offset), with c_t and e_t the
descriptor's centroid and extents (so the regression is relative to the observation and does not depend on
the object's distance or size); R from the 6-D output by Gram-Schmidt.

The ablation switches of `NetworkConfig` (`prior`, `fusion`, `decoupled`, `temporal`; `config.ABLATIONS`)
change the modules in place so that paper Table 2 can be reproduced with the same code.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.fusion import AsymmetricCrossModalAttention
from prompose_grasp.perception.network.geometry import GeometryEncoder
from prompose_grasp.perception.network.heads import RotationTranslationHead, ScaleHead
from prompose_grasp.perception.network.pose_tokens import DESCRIPTOR_DIM, PoseTokenExtractor
from prompose_grasp.perception.network.rotations import rotation_6d_to_matrix
from prompose_grasp.perception.network.temporal import TemporalTransformer
from prompose_grasp.perception.network.visual import build_visual_encoder

__all__ = ["ProMPoseNet", "canonicalize_points", "decode_pose"]

#: Smallest reference length |e_t| [m]: a cloud with (almost) no extent still gives finite offsets.
_MIN_REFERENCE_M = 1e-3
#: Smallest per-axis extent [m] when normalising a cloud into the unit box (a flat patch is not blown up).
_MIN_EXTENT_M = 1e-4
#: Log-size offsets are clamped to +-this before exp so a diverging head cannot overflow.
_MAX_LOG_SIZE = 5.0


def generic_prior_points(n: int, seed: int = 0) -> Tensor:
    """(n, 3) points uniformly on the surface of the unit cube [-0.5, 0.5]^3: the category-agnostic prior of
    the "without generative prior" ablation (deterministic for a seed)."""
    g = torch.Generator().manual_seed(seed)
    p = torch.rand(n, 3, generator=g) - 0.5
    face_axis = torch.randint(0, 3, (n,), generator=g)
    face_sign = torch.randint(0, 2, (n,), generator=g).to(p.dtype) - 0.5
    p[torch.arange(n), face_axis] = face_sign
    return p


def canonicalize_points(points: Tensor) -> Tensor:
    """Normalize(P_t): centre the (..., N, 3) cloud on its bounding-box centre and scale each axis to unit
    extent (paper section 3.3: the observed cloud in a unit axis-aligned bounding box)."""
    lo = points.amin(dim=-2, keepdim=True)
    hi = points.amax(dim=-2, keepdim=True)
    return (points - 0.5 * (lo + hi)) / (hi - lo).clamp_min(_MIN_EXTENT_M)


def decode_pose(
    rot6d: Tensor, translation_offset: Tensor, log_size_offset: Tensor, descriptor: Tensor
) -> dict[str, Tensor]:
    """Metric pose from the heads' outputs and d_t (..., 15) [m].

    Returns R (..., 3, 3), t (..., 3) [m], size (..., 3) [m].
    """
    centroid = descriptor[..., 0:3]
    reference = descriptor[..., 12:15].norm(dim=-1, keepdim=True).clamp_min(_MIN_REFERENCE_M)
    return {
        "R": rotation_6d_to_matrix(rot6d),
        "t": centroid + reference * translation_offset,
        "size": reference * torch.exp(log_size_offset.clamp(-_MAX_LOG_SIZE, _MAX_LOG_SIZE)),
    }


class ProMPoseNet(nn.Module):
    """The ProM-Pose network for a window of frames of one object.

    Args:
        config: the sizes (`network_config("tiny" | "paper")`).
        dinov2_dir: local DINOv2 folder overriding `config.dinov2_dir` (only for `visual_backbone="dinov2"`).
    """

    generic_prior: Tensor  # (prior_points, 3) buffer, see `generic_prior_points`

    def __init__(self, config: NetworkConfig, dinov2_dir: str | Path | None = None):
        super().__init__()
        self.config = config
        self.visual = build_visual_encoder(config, dinov2_dir)
        self.geometry = GeometryEncoder(config)
        self.fusion = AsymmetricCrossModalAttention(config)
        self.pose_tokens = PoseTokenExtractor(config)
        self.temporal = TemporalTransformer(config)
        self.rotation_translation_head = RotationTranslationHead(config)
        self.scale_head = ScaleHead(config)
        # Not stored in checkpoints: rebuilt from the config (only used by the `generic` prior ablation).
        self.register_buffer("generic_prior", generic_prior_points(config.prior_points), persistent=False)

    def forward(
        self,
        crops: Tensor,
        points: Tensor,
        descriptors: Tensor,
        prior_points: Tensor,
        text_tokens: Tensor,
        text_valid: Tensor,
        frame_valid: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """
        Args:
            crops: (B, n, 3, H, W) float RGB object crops in [0, 1].
            points: (B, n, N, 3) float observed points of the object, camera frame [m].
            descriptors: (B, n, 15) float d_t of those points [m] (`robust_descriptor(...).vector`).
            prior_points: (B, Np, 3) float canonical prior, unit box.
            text_tokens: (B, L, text_dim) float frozen text token features.
            text_valid: (B, L) bool, False for padding.
            frame_valid: (B, n) bool, False for padded / empty frames (default: all valid).
        Returns:
            `R` (B, n, 3, 3) R_cam_obj, `t` (B, n, 3) [m], `size` (B, n, 3) [m], `rot6d` (B, n, 6),
            `tokens` (B, n, 3, d) Z_t, `features` (B, n, 3, d) H, `aca_attention` (B*n, Nv, K),
            `prior_points` (B, Np, 3) the prior the network used (the input, or the generic cube).
        """
        B, n = points.shape[:2]
        if crops.shape[:2] != (B, n) or descriptors.shape != (B, n, DESCRIPTOR_DIM):
            raise InvalidInputError(
                f"crops (B, n, 3, H, W) and descriptors (B, n, {DESCRIPTOR_DIM}) must match points "
                f"(B, n, N, 3) "
                f"= {tuple(points.shape)}; got {tuple(crops.shape)} and {tuple(descriptors.shape)}"
            )
        if frame_valid is None:
            frame_valid = torch.ones(B, n, dtype=torch.bool, device=points.device)
        if self.config.prior == "generic":
            prior_points = self.generic_prior.to(points.dtype).expand(B, -1, -1)
        flat_points = points.reshape(B * n, *points.shape[2:])
        if self.config.decoupled:
            # One encoder, two streams in one call: the metric cloud and its canonicalised copy.
            both = self.geometry(torch.cat([flat_points, canonicalize_points(flat_points)], dim=0))
            metric_global = both["global"][: B * n]
            observed_canonical = both["tokens"][B * n :]
        else:  # ablation: the ACA sees the metric cloud's tokens
            metric = self.geometry(flat_points)
            metric_global, observed_canonical = metric["global"], metric["tokens"]
        prior = self.geometry(prior_points)["tokens"]  # (B, Mp, C), once per window
        prior_per_frame = prior.repeat_interleave(n, dim=0)

        visual = self.visual(crops.reshape(B * n, *crops.shape[2:]))["tokens"]
        fusion = self.fusion(
            visual,
            observed_canonical,
            prior_per_frame,
            text_tokens.repeat_interleave(n, dim=0),
            text_valid.repeat_interleave(n, dim=0),
        )
        flat_desc = descriptors.reshape(B * n, DESCRIPTOR_DIM)
        z = self.pose_tokens(fusion["fused"], flat_desc, metric_global)
        tokens = torch.stack([z["rotation"], z["translation"], z["scale"]], dim=1).reshape(B, n, 3, -1)
        h = self.temporal(tokens, frame_valid)["features"]
        rt = self.rotation_translation_head(h[:, :, 0], h[:, :, 1], prior)
        scale = self.scale_head(h[:, :, 2])
        pose = decode_pose(rt["rot6d"], rt["translation_offset"], scale["log_size_offset"], descriptors)
        return {
            **pose,
            "rot6d": rt["rot6d"],
            "tokens": tokens,
            "features": h,
            "aca_attention": fusion["attention"],
            "prior_points": prior_points,
        }
