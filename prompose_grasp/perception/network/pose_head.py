"""The trained network as a pose head: a window of masked RGB-D frames of one object + its prompt and prior ->
one metric 9-DoF pose per frame.

`NetworkPoseHead.load(weights)` rebuilds the network from a checkpoint (`load_estimator`, strict) next to the
frozen text encoder it was trained with. `prepare(frame)` does the preprocessing of training
(`data.object_crop`, `data.observed_points`, `robust_descriptor`) on the user's own mask, once per frame;
`predict(prepared, prompt, prior_points)` runs one forward pass over the last `config.window` prepared frames.
Nothing here reads ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import robust_descriptor
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.network.checkpoint import load_estimator
from prompose_grasp.perception.network.data import object_crop, observed_points
from prompose_grasp.perception.network.model import ProMPoseNet

__all__ = ["MaskedFrame", "NetworkPoseHead", "PreparedFrame"]

#: Frames whose mask holds fewer depth points than this are padding for the network (as in training).
MIN_POINTS = 32


@dataclass(frozen=True)
class MaskedFrame:
    """One frame of the object: (H, W, 3) uint8 RGB, (H, W) float depth [m], intrinsics, (H, W) bool mask."""

    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: CameraIntrinsics
    mask: np.ndarray


@dataclass(frozen=True, eq=False)
class PreparedFrame:
    """A frame as the network takes it: (S, S, 3) uint8 crop, (N, 3) float32 points [m], (15,) descriptor."""

    crop: np.ndarray
    points: np.ndarray
    descriptor: np.ndarray


class NetworkPoseHead:
    """A `ProMPoseNet` with its text encoder, ready for inference.

    Args:
        model: the network (eval mode is set here).
        text_encoder: the frozen phi_T whose token features the network was trained on (`encode_tokens`).
        device: where the network runs.
    """

    def __init__(self, model: ProMPoseNet, text_encoder: Any, device: str | torch.device = "cpu"):
        if int(text_encoder.dim) != model.config.text_dim:
            raise InvalidInputError(
                f"text encoder width {text_encoder.dim} != the network's text_dim {model.config.text_dim}"
            )
        self.model = model.to(device).eval()
        self.text_encoder = text_encoder
        self.device = torch.device(device)
        self._tokens: dict[str, np.ndarray] = {}

    @classmethod
    def load(
        cls, weights: str | Path, text_encoder: Any = None, device: str | torch.device = "cpu"
    ) -> NetworkPoseHead:
        """The pose head of a checkpoint (default text encoder: the embedded MiniLM)."""
        from prompose_grasp.perception.text import default_text_encoder

        return cls(load_estimator(weights, device), text_encoder or default_text_encoder("cpu"), device)

    @property
    def window(self) -> int:
        return self.model.config.window

    def _text_tokens(self, prompt: str) -> np.ndarray:
        if prompt not in self._tokens:
            self._tokens[prompt] = np.asarray(self.text_encoder.encode_tokens(prompt), dtype=np.float32)
        return self._tokens[prompt]

    def prepare(self, frame: MaskedFrame) -> PreparedFrame | None:
        """Crop, sampled points and descriptor of the masked object; None with < `MIN_POINTS` depth points."""
        cfg = self.model.config
        mask = np.asarray(frame.mask, dtype=bool)
        if mask.shape != frame.depth_m.shape[:2]:
            raise InvalidInputError(f"mask {mask.shape} does not match depth {frame.depth_m.shape}")
        pts = observed_points(frame.depth_m, frame.intrinsics, mask, cfg.observed_points, MIN_POINTS)
        if pts is None:
            return None
        crop = object_crop(frame.rgb, mask, cfg.crop_px)
        return PreparedFrame(crop, pts, robust_descriptor(pts).vector.astype(np.float32))

    @torch.no_grad()
    def predict(
        self, frames: Sequence[PreparedFrame | None], prompt: str, prior_points: np.ndarray
    ) -> list[Pose9D | None]:
        """Poses (camera frame) of the object in each of the last `window` frames, oldest first.

        Args:
            frames: the object's prepared frames (`prepare`), oldest first; None for a frame without enough
                points. Only the last `window` are used.
            prompt: the text naming the object (as for the prior).
            prior_points: (Np, 3) canonical prior in the unit box (`ShapePrior.points`; resampled to the
                network's prior size when it differs).
        Returns:
            one entry per used frame; None where that frame was None.
        Raises:
            InvalidInputError: no frames, an empty prompt, a bad prior, or no usable frame.
        """
        cfg = self.model.config
        if not frames:
            raise InvalidInputError("no frames to estimate from")
        if not prompt.strip():
            raise InvalidInputError("prompt is empty")
        prior = np.asarray(prior_points, dtype=np.float32)
        if prior.ndim != 2 or prior.shape[1] != 3 or len(prior) < 1 or not np.isfinite(prior).all():
            raise InvalidInputError(f"prior_points must be a finite (Np, 3) array, got {prior.shape}")
        if len(prior) != cfg.prior_points:
            # the prior is a uniform surface sample: a seeded subset / repetition keeps it uniform
            idx = np.random.default_rng(0).choice(len(prior), cfg.prior_points, len(prior) < cfg.prior_points)
            prior = prior[idx]
        used = list(frames)[-cfg.window :]
        valid = np.array([f is not None for f in used])
        if not valid.any():
            raise InvalidInputError(f"no frame has >= {MIN_POINTS} depth points inside the mask")
        fill = next(f for f in used if f is not None)
        # invalid frames are padding (masked out as keys), filled with a valid frame's data as in training
        window: list[PreparedFrame] = [f if f is not None else fill for f in used]
        tokens = self._text_tokens(prompt)

        def batch(a: np.ndarray) -> torch.Tensor:  # one window: a leading batch axis of 1
            return torch.as_tensor(a[None], device=self.device)

        out = self.model(
            crops=batch(np.stack([f.crop for f in window]).transpose(0, 3, 1, 2).astype(np.float32) / 255.0),
            points=batch(np.stack([f.points for f in window]).astype(np.float32)),
            descriptors=batch(np.stack([f.descriptor for f in window]).astype(np.float32)),
            prior_points=batch(prior),
            text_tokens=batch(tokens),
            text_valid=batch(np.ones(len(tokens), dtype=bool)),
            frame_valid=batch(valid),
        )
        R, t, size = (out[k][0].double().cpu().numpy() for k in ("R", "t", "size"))
        return [Pose9D(R[i], t[i], size[i]) if valid[i] else None for i in range(len(used))]
