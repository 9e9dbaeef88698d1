"""Robot self-filtering (`grasp.self_filter.robot_pixel_mask`): the depth pixels within a margin of the
robot's capsules, against a brute-force distance computed independently (the rendered case: tests/sim)."""

from __future__ import annotations

import numpy as np

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp.self_filter import robot_pixel_mask


def _brute_force_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray, n: int = 20001) -> np.ndarray:
    """Distance of each point to a dense sampling of the segment (no projection formula)."""
    S = p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)
    return np.array([np.min(np.linalg.norm(S - p, axis=1)) for p in P])


def test_mask_matches_a_brute_force_distance():
    # Capsules named "gripper" have the distance test alone (no band along the rays: a held object lies in
    # front of the gripper).
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
        ("gripper", np.array([-0.2, -0.1, 0.0]), np.array([0.3, 0.15, 0.2]), 0.06),
        ("gripper", np.array([0.3, 0.15, 0.2]), np.array([0.35, -0.2, 0.1]), 0.04),
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


def _segment_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distance of points (..., 3) to the segment: the clamped projection, written out here."""
    d = p1 - p0
    s = np.clip(((P - p0) @ d) / (d @ d), 0.0, 1.0)
    return np.linalg.norm(P - (p0 + s[..., None] * d), axis=-1)


def _first_entry(dirs: np.ndarray, p0: np.ndarray, p1: np.ndarray, R: float) -> np.ndarray:
    """(N,) range [m] where each unit ray from the camera first comes within R of the segment (sampled
    every 0.5 mm between 0.5 and 1.2 m, where the link is), inf where it never does."""
    t = np.arange(0.5, 1.2, 0.0005)
    inside = _segment_distance(dirs[:, None, :] * t[None, :, None], p0, p1) <= R
    return np.where(inside.any(axis=1), t[np.argmax(inside, axis=1)], np.inf)


def test_an_arm_link_takes_the_readings_along_its_rays_within_the_noise_band():
    # A link 0.8-0.9 m in front of a camera, readings scattered along the rays: those inside its silhouette
    # between its front less 3 % of the range and its back plus that are the arm (depth noise moves a reading
    # along its ray); readings far behind it (the table past its edge) and far in front (an object before
    # it) are not, unless within the margin of the capsule.
    rng = np.random.default_rng(5)
    K = CameraIntrinsics(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
    T_base_cam = make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 1.0])  # 1 m above, looking down
    p0, p1, r, margin = np.array([-0.25, 0.0, 0.15]), np.array([0.25, 0.05, 0.1]), 0.05, 0.03
    v, u = np.mgrid[0:48, 0:64]
    dirs = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], axis=-1).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    q0, q1 = (np.array([p[0], -p[1], 1.0 - p[2]]) for p in (p0, p1))  # the link in the camera frame
    front = _first_entry(dirs, q0, q1, r + margin)
    seen = np.isfinite(front)
    assert 100 < seen.sum() < 0.5 * len(front)
    # readings around the front of the link (+-12 cm), and 0.4-0.6 m past it where its rays miss it
    reading = np.where(seen, front + rng.uniform(-0.12, 0.12, len(front)), rng.uniform(1.3, 1.5, len(front)))
    depth = (reading * dirs[:, 2]).reshape(48, 64).astype(np.float32)
    mask = robot_pixel_mask(depth, K, T_base_cam, [("upper_arm_link", p0, p1, r)], margin).ravel()
    band = np.maximum(margin, 0.03 * reading)
    off = reading - front
    # readings within the band of the link's (grown) surface along their rays; the silhouette is drawn from
    # spheres 1 cm apart along the axis: within 5 mm of the band's edge a reading may go either way
    clear_in = seen & (off >= -band + 0.005) & (off <= band - 0.005)
    clear_front = seen & (off < -band - 0.005)
    P = dirs * reading[:, None]
    near_axis = _segment_distance(P[clear_front], q0, q1) <= r + margin
    assert clear_in.sum() > 50 and clear_front.sum() > 20
    assert mask[clear_in].all()  # on the link, noise included
    assert (mask[clear_front] == near_axis).all()  # in front: only what the distance test takes
    assert not mask[~seen & (reading > 1.3)].any()  # the floor past the link's edge
