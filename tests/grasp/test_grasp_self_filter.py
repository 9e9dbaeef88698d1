"""Robot self-filtering (`grasp.planner.robot_pixel_mask`): the depth pixels within a margin of the robot's
capsules, against a brute-force distance computed independently (the rendered case: tests/sim)."""

from __future__ import annotations

import numpy as np

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp.planner import robot_pixel_mask


def _brute_force_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray, n: int = 20001) -> np.ndarray:
    """Distance of each point to a dense sampling of the segment (no projection formula)."""
    S = p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)
    return np.array([np.min(np.linalg.norm(S - p, axis=1)) for p in P])


def test_mask_matches_a_brute_force_distance():
    rng = np.random.default_rng(3)
    K = CameraIntrinsics(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
    depth = rng.uniform(0.6, 1.4, size=(48, 64)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0  # holes: never on the robot
    depth[0, 0] = np.nan
    # The camera 1 m above the base looking down (its z along -z of base), turned 30 deg about its axis.
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, -1.0, -1.0])
    T_base_cam = make_T(R, [0.1, 0.0, 1.0])
    capsules = [
        ("link_a", np.array([-0.2, -0.1, 0.0]), np.array([0.3, 0.15, 0.2]), 0.06),
        ("link_b", np.array([0.3, 0.15, 0.2]), np.array([0.35, -0.2, 0.1]), 0.04),
    ]
    margin = 0.02
    mask = robot_pixel_mask(depth, K, T_base_cam, capsules, margin)

    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    P_cam = np.stack([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z], axis=1)
    P = P_cam @ T_base_cam[:3, :3].T + T_base_cam[:3, 3]
    excess = np.min([_brute_force_distance(P, p0, p1) - (r + margin) for _, p0, p1, r in capsules], axis=0)
    # The dense sampling overestimates a distance by at most half a sample step (0.03 mm here) and float32
    # depth rounds ~1e-7 m: points within 0.1 mm of the boundary may go either way and are left out.
    clear = np.abs(excess) > 1e-4
    assert clear.sum() > 0.95 * len(excess)
    np.testing.assert_array_equal(mask[v, u][clear], (excess <= 0)[clear])
    assert 50 < mask.sum() < mask.size / 2  # the case has both kinds of pixels
    assert not mask[depth == 0].any() and not mask[0, 0]
    # No capsules: nothing is the robot.
    assert not robot_pixel_mask(depth, K, T_base_cam, [], margin).any()
