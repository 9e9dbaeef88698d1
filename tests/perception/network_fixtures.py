"""Test inputs for the network: random batches and object tracks built from shape priors without rendering.

`synthetic_tracks` poses a family prior (random size and pose in front of a camera that turns a few degrees
per frame), keeps the points whose normals face the camera (the visible side, as a depth camera sees it), adds
1 mm noise, and splats them into a shaded object crop. Text tokens are fixed random features per family (a
stand-in for the frozen encoder's output, so the tests need not load MiniLM).
"""

from __future__ import annotations

import numpy as np
import torch

from prompose_grasp.geometry.pointcloud import farthest_point_sampling
from prompose_grasp.geometry.se3 import so3_exp
from prompose_grasp.perception.network import NetworkConfig, ObjectTrack
from prompose_grasp.perception.priors import PriorLibrary

FAMILIES = ("box", "can", "bowl", "cup", "carton", "tube", "sack", "ball")
_LIBRARY = PriorLibrary()


def random_inputs(config: NetworkConfig, B: int = 2, n: int | None = None, L: int = 5, seed: int = 0) -> dict:
    """Seeded random network inputs (B windows of n frames), objects about 0.8 m in front of the camera."""
    g = torch.Generator().manual_seed(seed)
    n = config.window if n is None else n
    points = torch.randn(B, n, config.observed_points, 3, generator=g) * 0.04 + torch.tensor([0.0, 0.0, 0.8])
    desc = torch.cat(
        [points.mean(2), torch.eye(3).reshape(1, 1, 9).expand(B, n, 9), points.amax(2) - points.amin(2)],
        dim=-1,
    )
    return {
        "crops": torch.rand(B, n, 3, config.crop_px, config.crop_px, generator=g),
        "points": points,
        "descriptors": desc,
        "prior_points": torch.rand(B, config.prior_points, 3, generator=g) - 0.5,
        "text_tokens": torch.randn(B, L, config.text_dim, generator=g),
        "text_valid": torch.ones(B, L, dtype=torch.bool),
        "frame_valid": torch.ones(B, n, dtype=torch.bool),
    }


def _crop(points_cam: np.ndarray, normals_cam: np.ndarray, colour: np.ndarray, crop_px: int) -> np.ndarray:
    uv = points_cam[:, :2] / points_cam[:, 2:3]
    lo, hi = uv.min(0), uv.max(0)
    side = float((hi - lo).max()) * 1.2 + 1e-9
    px = ((uv - 0.5 * (lo + hi)) / side + 0.5) * crop_px
    img = np.zeros((crop_px, crop_px, 3), dtype=np.uint8)
    shade = np.clip(-normals_cam[:, 2], 0.2, 1.0)[:, None]
    ij = np.clip(px.astype(int), 0, crop_px - 1)
    img[ij[:, 1], ij[:, 0]] = (colour * shade * 255).astype(np.uint8)
    return img


def synthetic_tracks(config: NetworkConfig, count: int, frames: int, seed: int) -> list[ObjectTrack]:
    """`count` tracks of `frames` frames each, seeded."""
    rng = np.random.default_rng(seed)
    text = {
        f: np.random.default_rng([7, i]).normal(size=(3, config.text_dim)).astype(np.float32)
        for i, f in enumerate(FAMILIES)
    }
    tracks = []
    for k in range(count):
        family = FAMILIES[k % len(FAMILIES)]
        prior = _LIBRARY.family_prior(family, n_points=config.prior_points, seed=0)
        dense = _LIBRARY.family_prior(family, n_points=4000, seed=1)
        size = prior.typical_size_m * rng.uniform(0.7, 1.3, size=3)
        # Upright-ish object seen from above the table: tilt towards the camera, random yaw.
        R0 = so3_exp([rng.uniform(-1.2, -0.5), 0.0, 0.0]) @ so3_exp([0.0, rng.uniform(-np.pi, np.pi), 0.0])
        t0 = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05), rng.uniform(0.55, 0.9)])
        turn = rng.uniform(-0.1, 0.1)  # rad per frame about the camera's y axis, around the object
        colour = rng.uniform(0.2, 1.0, size=3)
        crops, pts, Rs, ts = [], [], [], []
        for f in range(frames):
            D = so3_exp([0.0, turn * f, 0.0])
            R, t = D @ R0, D @ t0
            p = (dense.points * size) @ R.T + t
            nrm = (dense.normals / size) @ R.T
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            vis = (nrm * p).sum(1) < 0.0
            p_vis = p[vis] + rng.normal(scale=0.001, size=(int(vis.sum()), 3))
            pts.append(p_vis[farthest_point_sampling(p_vis, config.observed_points)].astype(np.float32))
            crops.append(_crop(p[vis], nrm[vis], colour, config.crop_px))
            Rs.append(R)
            ts.append(t)
        tracks.append(
            ObjectTrack(
                scene=f"synthetic_{seed}_{k}",
                instance_id=k + 1,
                category=family,
                prompt=family,
                symmetry=prior.symmetry,
                crops=np.stack(crops),
                points=np.stack(pts),
                frame_valid=np.ones(frames, dtype=bool),
                R_cam_obj=np.asarray(Rs, dtype=np.float32),
                t_cam_obj_m=np.asarray(ts, dtype=np.float32),
                size_m=np.tile(size, (frames, 1)).astype(np.float32),
                text_tokens=text[family],
                prior_points=np.asarray(prior.points, dtype=np.float32),
            )
        )
    return tracks
