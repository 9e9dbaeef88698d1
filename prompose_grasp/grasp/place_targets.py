"""Place targets from what the camera sees: a grounded object as a bin or a surface, and the checks of an
object against a target (already on it, no room on it).

A command whose place phrase names no fixture of the cell ("in the white bowl", "on the tea box") is grounded
in the image like the object; its estimated box becomes a bin (into a container) or the surface of its top.
"""

from __future__ import annotations

import numpy as np

from prompose_grasp.grasp.extent import up_of
from prompose_grasp.grasp.place import PlaceTarget, footprint
from prompose_grasp.grasp.types import ObjectModel, Plane

__all__ = ["CONTAINERS", "at_target", "no_room", "place_target_on"]

#: Prior families that hold things inside them (a place "on" one of them puts the object in).
CONTAINERS = ("bowl", "cup", "mug", "bin", "basket", "bucket", "pot", "tray")
#: A container's wall takes ~8 % of its width each side: the inner floor's half extents are this share [-] ...
_INNER_SHARE = 0.84
#: ... its floor is ~10 % of its height up, and the inside ~90 % of its height deep [-].
_FLOOR_SHARE = 0.1
_DEPTH_SHARE = 0.9


def place_target_on(obj: ObjectModel, support: Plane | None, container: bool) -> PlaceTarget:
    """The place target an object in base makes: its inner floor as a bin when it is a `container`, else the
    surface of its top. The object axis nearest the support normal is its height; the other two span its
    footprint (the target's x along the first of them, z the support normal)."""
    up = up_of(support)
    R = obj.pose.R
    k_up = int(np.argmax(np.abs(R.T @ up)))
    others = [i for i in range(3) if i != k_up]
    x_axis = R[:, others[0]] - (R[:, others[0]] @ up) * up
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(up, x_axis)
    half_xy = obj.pose.size[others] / 2.0
    h = float(obj.pose.size[k_up])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x_axis, y_axis, up])
    if container:
        T[:3, 3] = obj.pose.t - 0.5 * h * up + _FLOOR_SHARE * h * up
        return PlaceTarget("bin", T, _INNER_SHARE * half_xy, _DEPTH_SHARE * h)
    T[:3, 3] = obj.pose.t + 0.5 * h * up
    return PlaceTarget("surface", T, half_xy, 0.0)


def at_target(obj: ObjectModel, target: PlaceTarget) -> bool:
    """The object's centre is above the target's surface, within its footprint (it was put there)."""
    T = target.T_base_surface
    local = T[:3, :3].T @ (obj.pose.t - T[:3, 3])
    return bool(np.all(np.abs(local[:2]) <= target.half_extents_xy_m) and -0.02 < local[2] < 1.0)


def no_room(carried: ObjectModel, target: PlaceTarget | None) -> bool:
    """The carried box is wider than a surface or bin place target in both orientations (the footprint
    `plan_place` lays out): no place can take it (a stack's estimate that merged two cartons, 0.75 m across,
    against a 0.5 m belt). A pallet's pattern is laid out by its own planner: never "no room" here."""
    if target is None or target.kind == "pallet":
        return False
    R = np.asarray(target.T_base_surface, dtype=np.float64)[:3, :3].T @ carried.pose.R
    half, _ = footprint(R, np.asarray(carried.pose.size, dtype=np.float64))
    room = np.asarray(target.half_extents_xy_m, dtype=np.float64)
    return bool(np.any(half > room) and np.any(half[::-1] > room))
