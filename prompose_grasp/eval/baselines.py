"""The baseline a user would otherwise write: the oriented bounding box of the masked points as a 9-DoF box.

Benchmarks compare the estimator against it in the same run (DESIGN.md).
"""

from __future__ import annotations

import numpy as np
import trimesh

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.perception.grounding import SupportPlane

__all__ = ["obb_baseline"]


def obb_baseline(
    points_cam: np.ndarray, support_plane: SupportPlane | None = None, extend_to_plane: bool = True
) -> Pose9D:
    """Oriented bounding box of the observed points, made a 9-DoF box as a careful user would.

    Steps: the points are depth-clipped to [p5, p95] (as the paper's descriptor does, against flying pixels);
    `trimesh.bounds.oriented_bounds` gives the minimum-volume box; its axis closest to "up" (the support
    normal, else the camera's -y) becomes +y, the longer of the other two +x, z = x cross y. With a support
    plane the box's bottom is extended down to the plane, since objects stand on it (the amodal height).

    Args:
        points_cam: (N, 3) masked depth points in the camera frame [m], N >= 4.
        support_plane: the plane the object stands on, if known (its normal picks +y).
        extend_to_plane: extend the box's bottom down to the plane (the careful user's amodal height).
    """
    P = np.asarray(points_cam, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 4:
        raise InvalidInputError(f"points_cam must be (N, 3) with N >= 4, got {P.shape}")
    z_lo, z_hi = np.percentile(P[:, 2], [5.0, 95.0])
    clipped = P[(P[:, 2] >= z_lo) & (P[:, 2] <= z_hi)]
    if len(clipped) >= 4:
        P = clipped
    to_origin, extents = trimesh.bounds.oriented_bounds(P)
    T_cam_box = np.linalg.inv(to_origin)
    axes, centre = T_cam_box[:3, :3], T_cam_box[:3, 3]
    up = support_plane.normal_cam if support_plane is not None else np.array([0.0, -1.0, 0.0])
    iy = int(np.argmax(np.abs(axes.T @ up)))
    y = axes[:, iy] * np.sign(axes[:, iy] @ up)
    ix, iz = sorted((i for i in range(3) if i != iy), key=lambda i: -extents[i])
    x = axes[:, ix]
    R = np.column_stack([x, y, np.cross(x, y)])
    size = np.array([extents[ix], extents[iy], extents[iz]], dtype=np.float64)
    if support_plane is not None and extend_to_plane:
        top = centre + 0.5 * size[1] * y
        top_height = float(support_plane.height_m(top))
        if top_height > 0.0:
            # y is within a few degrees of the normal; the division keeps the top face where it was
            height = top_height / max(float(y @ support_plane.normal_cam), 0.5)
            centre, size[1] = top - 0.5 * height * y, height
    return Pose9D(R, centre, np.maximum(size, 1e-4))
