"""Robot self-filtering: which depth pixels and points lie on the robot itself.

A camera that sees the arm (a fixed camera with the arm parked in view, or the wrist camera seeing its own
gripper) would otherwise offer a link as an object to ground, and a reading off the arm would stand in the
collision scene as an obstacle. The robot is modelled by its link capsules at the joints of the capture plus
one capsule around the gripper (`robot_self_capsules`); `robot_pixel_mask` marks the pixels on them, and
`without_robot` drops their depth readings from a frame (`grasp.bins.without_bins` does the same for the
cell's bins).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.distance import segment_distance
from prompose_grasp.geometry.pointcloud import back_project, valid_depth_mask
from prompose_grasp.geometry.se3 import as_transform, invert_T, transform_points
from prompose_grasp.grasp.grippers import ParallelJawGeometry, SuctionCupGeometry
from prompose_grasp.robot.interfaces import RGBDFrame
from prompose_grasp.robot.model import RobotModel

__all__ = ["robot_pixel_mask", "robot_self_capsules", "without_robot"]


def robot_self_capsules(
    robot: RobotModel, gripper: ParallelJawGeometry | SuctionCupGeometry, q: np.ndarray
) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """The arm's capsules at q plus one capsule around the gripper (flange to tcp, radius of its widest part),
    in `base`: where the camera sees the robot itself."""
    T_flange = robot.fk(q)
    lo, hi = (
        np.min([b[0] for b in gripper.hull_boxes().values()], axis=0),
        np.max([b[1] for b in gripper.hull_boxes().values()], axis=0),
    )
    radius = float(np.linalg.norm(np.maximum(np.abs(lo[:2]), np.abs(hi[:2]))))
    tip = (T_flange @ gripper.T_flange_tcp)[:3, 3]
    return [*robot.capsules_in_base(q), ("gripper", T_flange[:3, 3], tip, radius)]


#: Along its ray a depth reading is off by the sensor's noise: a D400-class stereo camera's is ~1 % of the
#: range rms, so among the ~10^4 pixels of an arm in view a few read 3-4 cm nearer than its surface. A reading
#: inside the arm's silhouette no nearer than its front less this share of the range is the arm.
_RAY_BAND_FRACTION = 0.03
#: The capsules' axes are sampled this finely for their silhouettes [m] (a union of spheres is the capsule).
_SILHOUETTE_STEP_M = 0.01


def _arm_silhouette(
    shape: tuple[int, int],
    intrinsics: CameraIntrinsics,
    caps_cam: Sequence[tuple[np.ndarray, float]],
    margin_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) ranges [m] along each pixel's ray where it enters the capsules (grown by `margin_m`) first and
    leaves them again, inf where it misses them all: each capsule as spheres along its axis
    (`_SILHOUETTE_STEP_M` apart; a union of spheres is the capsule), each ray's entry and exit exact per
    sphere, overlapping spans merged."""
    H, W = shape
    front = np.full(shape, np.inf)
    back = np.full(shape, np.inf)
    for (p0, p1), radius in caps_cam:
        R = radius + margin_m
        n = max(2, int(np.ceil(np.linalg.norm(p1 - p0) / _SILHOUETTE_STEP_M)) + 1)
        for q in np.linspace(p0, p1, n):
            if q[2] <= R:  # the sphere reaches behind the camera: no silhouette to draw
                continue
            u = intrinsics.fx * q[0] / q[2] + intrinsics.cx
            v = intrinsics.fy * q[1] / q[2] + intrinsics.cy
            rad = intrinsics.fx * R / np.sqrt(q[2] ** 2 - R**2) + 1.0  # the projected radius, a pixel more
            x0, x1 = max(0, int(u - rad)), min(W, int(u + rad) + 2)
            y0, y1 = max(0, int(v - rad)), min(H, int(v + rad) + 2)
            if x0 >= x1 or y0 >= y1:
                continue
            yy, xx = np.mgrid[y0:y1, x0:x1]
            d = np.stack([(xx - intrinsics.cx) / intrinsics.fx, (yy - intrinsics.cy) / intrinsics.fy,
                          np.ones(xx.shape)], axis=-1)  # fmt: skip
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            along = d @ q
            half = np.sqrt(np.maximum(R**2 - (q @ q - along**2), 0.0))
            hit = R**2 >= q @ q - along**2
            entry, exit_ = along - half, along + half
            f, b = front[y0:y1, x0:x1], back[y0:y1, x0:x1]
            nearer = hit & (entry < f)
            joins = hit & ~nearer & (entry <= b)  # overlaps the span already there: one surface
            # a nearer span replaces the one there, or extends it when the two overlap
            overlaps = nearer & (exit_ >= f)
            b[nearer & ~overlaps] = exit_[nearer & ~overlaps]
            b[overlaps] = np.maximum(b[overlaps], exit_[overlaps])
            f[nearer] = entry[nearer]
            b[joins] = np.maximum(b[joins], exit_[joins])
    return front, back


def robot_pixel_mask(
    depth_m: np.ndarray,
    intrinsics: CameraIntrinsics,
    T_base_cam: ArrayLike,
    capsules: Sequence[tuple[str, np.ndarray, np.ndarray, float]],
    margin_m: float = 0.03,
) -> np.ndarray:
    """(H, W) bool: the pixels whose depth reading lies on the robot itself (`robot_self_capsules` at the
    joints of the capture, (name, p0, p1, radius) in `base`): within `margin_m` of a capsule, or, for the
    arm's links, on a ray through them (grown by `margin_m`) between where it enters and leaves them, widened
    by `_RAY_BAND_FRACTION` of the range (noise moves a reading along its ray, off the surface by more than
    any fixed margin on a far arm; the table seen past the arm's edge lies farther). The gripper's capsule
    has no such band: an object held in the jaws lies in front of it.

    Robot self-filtering: a camera that sees the arm (a fixed camera with the arm parked in view) would
    otherwise offer a link as an object to ground ("a large black box-shaped object", 0.49 m tall, next to
    the tea box), and a reading off the arm would stand in the collision scene as an obstacle. Pixels without
    a reading are never on the robot.
    """
    D = np.asarray(depth_m)
    T = as_transform(T_base_cam, "T_base_cam")
    out = np.zeros(D.shape, dtype=bool)
    valid = valid_depth_mask(D)
    if not capsules or not valid.any():
        return out
    idx = np.flatnonzero(valid)
    P = back_project(D, intrinsics)  # camera frame, row-major order of the valid pixels
    # The capsules move to the camera frame (a few end points) rather than the frame's ~300k points to base.
    T_cam_base = invert_T(T)
    caps = [(transform_points(T_cam_base, np.stack([p0, p1])), float(r)) for _, p0, p1, r in capsules]
    # Only points inside the capsules' common bounding box (grown by radius + margin) can be on the robot.
    ends = np.concatenate([e for e, _ in caps])
    grow = max(r for _, r in caps) + float(margin_m)
    near = np.flatnonzero(np.all((P >= ends.min(axis=0) - grow) & (P <= ends.max(axis=0) + grow), axis=1))
    Pn = P[near]
    hit = np.zeros(len(Pn), dtype=bool)
    for (p0, p1), radius in caps:
        hit |= segment_distance(Pn, p0, p1) <= radius + float(margin_m)
    on_robot = near[hit]
    out.ravel()[idx[on_robot]] = True
    arm = [c for c, (name, *_) in zip(caps, capsules) if name != "gripper"]
    if arm:
        front, back = _arm_silhouette(D.shape, intrinsics, arm, float(margin_m))
        front, back = front.ravel()[idx], back.ravel()[idx]
        rng = np.linalg.norm(P, axis=1)
        band = np.maximum(float(margin_m), _RAY_BAND_FRACTION * rng)
        on_ray = np.isfinite(front) & (rng >= front - band) & (rng <= back + band)
        out.ravel()[idx[on_ray]] = True
    return out


def without_robot(
    frame: RGBDFrame,
    robot: RobotModel,
    gripper: ParallelJawGeometry | SuctionCupGeometry,
    q: np.ndarray,
    margin_m: float,
) -> RGBDFrame:
    """`frame` (with its `T_base_cam`) with no depth reading where it sees the robot at joints `q`
    (`robot_pixel_mask` within `margin_m` of `robot_self_capsules`); the same frame when it sees none."""
    assert frame.T_base_cam is not None
    capsules = robot_self_capsules(robot, gripper, q)
    on_robot = robot_pixel_mask(frame.depth_m, frame.intrinsics, frame.T_base_cam, capsules, margin_m)
    if not on_robot.any():
        return frame
    return dataclasses.replace(frame, depth_m=np.where(on_robot, np.float32(0.0), frame.depth_m))
