"""An object's extent along its support's normal: its height, its top, and the box it is carried as.

The estimated box is amodal and can reach down through a stack (the height of a carton lying on other
cartons is not seen from above); `carried` caps it at the tallest object the cell handles, its top kept.
"""

from __future__ import annotations

import numpy as np

from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.grasp.types import ObjectModel, Plane

__all__ = ["carried", "height", "overlaps", "plane_z", "top_height", "up_of"]


def up_of(support: Plane | None) -> np.ndarray:
    """(3,) the support's normal, base +z without a support."""
    return np.array([0.0, 0.0, 1.0]) if support is None else np.asarray(support.normal)


def plane_z(plane: Plane) -> float:
    """Height of a plane where it passes under the base origin, along its normal [m]."""
    return float(-plane.offset_m)


def height(obj: ObjectModel, support: Plane | None) -> float:
    """Extent of the object's box along the support normal (base +z without one) [m]."""
    return float(np.abs(obj.pose.R.T @ up_of(support)) @ obj.pose.size)


def top_height(obj: ObjectModel, support: Plane | None) -> float:
    """Height of the top of the object's box along the support normal [m]."""
    return float(obj.pose.t @ up_of(support) + 0.5 * height(obj, support))


def carried(target: ObjectModel, support: Plane | None, max_height_m: float | None) -> ObjectModel:
    """The target as carried and put down: its box capped at `max_height_m` along the support normal, the
    top kept (the estimate's top face is what the camera saw); the target itself when it is not taller."""
    h = height(target, support)
    if max_height_m is None or h <= max_height_m:
        return target
    up = up_of(support)
    pose = target.pose
    k_up = int(np.argmax(np.abs(pose.R.T @ up)))
    size = np.array(pose.size, dtype=np.float64)
    size[k_up] = max_height_m
    t = pose.t + 0.5 * (h - max_height_m) * up
    return ObjectModel(target.name, Pose9D(pose.R, t, size), family=target.family)


def overlaps(a: ObjectModel, b: ObjectModel) -> bool:
    """The two boxes' centres lie within each other's half extents (the same object seen twice)."""
    d = np.abs(a.pose.t - b.pose.t)
    return bool(np.all(d <= np.maximum(a.pose.size, b.pose.size) / 2.0))
