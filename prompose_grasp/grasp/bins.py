"""The cell's bins as fixtures: no object to pick, an obstacle to keep clear of.

A tote on the table is seen like any object (a large box-shaped thing, 30 x 25 x 11 cm), which a prompt for a
tray, a box or a frying pan can ground: the arm then grasps the bin's wall. The cell knows its bins (the place
targets, measured once at setup), so `without_bins` drops the depth readings on a bin's floor and walls
(`on_bin`) before anything is grounded, and the collision scene holds its walls as fixture boxes
(`bin_walls`) whether or not a camera sees them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from prompose_grasp.geometry.pointcloud import back_project, valid_depth_mask
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import as_transform, transform_points
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.types import ObjectModel
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["BIN_MARGIN_M", "BIN_WALL_M", "bin_walls", "on_bin", "without_bins"]

#: A reading this near a bin's floor or walls is the bin: depth noise of a D400-class camera is ~1 % of the
#: range, 8 mm at 0.8 m [m].
BIN_MARGIN_M = 0.01

#: A bin's walls stand outside its floor's half extents, as thick as this at most: a plastic tote's are 3-10
#: mm, a wooden crate's up to 2 cm [m].
BIN_WALL_M = 0.02


def bin_walls(target: PlaceTarget, thickness_m: float = BIN_WALL_M) -> list[ObjectModel]:
    """The four walls of a bin target as fixture boxes in `base` (just outside its floor's half extents,
    from the floor up `wall_height_m`); none for the other kinds. The collision scene keeps them whether or
    not the camera sees them (`without_bins` drops the readings on them before grounding)."""
    if target.kind != "bin" or target.wall_height_m <= 0.0:
        return []
    T = target.T_base_surface
    hx, hy = target.half_extents_xy_m
    h, t = float(target.wall_height_m), float(thickness_m)
    walls = []
    for name, centre, size in (
        ("+x", (hx + t / 2, 0.0), (t, 2 * (hy + t))),
        ("-x", (-hx - t / 2, 0.0), (t, 2 * (hy + t))),
        ("+y", (0.0, hy + t / 2), (2 * hx, t)),
        ("-y", (0.0, -hy - t / 2), (2 * hx, t)),
    ):
        c = T[:3, :3] @ np.array([centre[0], centre[1], h / 2]) + T[:3, 3]
        walls.append(
            ObjectModel(f"bin wall {name}", Pose9D(T[:3, :3], c, np.array([*size, h])), kind="fixture")
        )
    return walls


def on_bin(points_base: np.ndarray, target: PlaceTarget, margin_m: float) -> np.ndarray:
    """(N,) bool: the points on a bin target itself, its floor or its walls: inside its outer box (the floor's
    half extents grown by `BIN_WALL_M`, from `BIN_WALL_M` under the floor to the walls' top) grown by
    `margin_m`, and not in the space it holds (the floor's half extents less `margin_m`, more than `margin_m`
    above the floor). An object in the bin keeps all but its lowest `margin_m` and the strip by a wall; all
    False for the other kinds."""
    P = np.asarray(points_base, dtype=np.float64).reshape(-1, 3)
    if target.kind != "bin":
        return np.zeros(len(P), dtype=bool)
    T = target.T_base_surface
    local = (P - T[:3, 3]) @ T[:3, :3]
    a = np.abs(local[:, :2])
    z = local[:, 2]
    half = target.half_extents_xy_m
    outer = np.all(a <= half + BIN_WALL_M + margin_m, axis=1) & (z >= -BIN_WALL_M - margin_m)
    outer &= z <= target.wall_height_m + margin_m
    held_space = np.all(a < half - margin_m, axis=1) & (z > margin_m)
    return outer & ~held_space


def without_bins(
    frame: RGBDFrame, targets: Sequence[PlaceTarget], margin_m: float = BIN_MARGIN_M
) -> RGBDFrame:
    """`frame` (with its `T_base_cam`) with no depth reading on the floor or walls of any bin among `targets`
    (`on_bin` within `margin_m`); the same frame when it sees none. A tote on the table otherwise reads
    as a large box-shaped object, which a prompt for a tray, a box or a pan can ground."""
    bins = [t for t in targets if t.kind == "bin"]
    if not bins:
        return frame
    assert frame.T_base_cam is not None
    D = np.asarray(frame.depth_m)
    valid = valid_depth_mask(D)
    if not valid.any():
        return frame
    P = transform_points(as_transform(frame.T_base_cam, "T_base_cam"), back_project(D, frame.intrinsics))
    hit = np.zeros(len(P), dtype=bool)
    for t in bins:
        hit |= on_bin(P, t, margin_m)
    if not hit.any():
        return frame
    drop = np.zeros(D.shape, dtype=bool)
    drop.ravel()[np.flatnonzero(valid)[hit]] = True
    return dataclasses.replace(frame, depth_m=np.where(drop, np.float32(0.0), frame.depth_m))
