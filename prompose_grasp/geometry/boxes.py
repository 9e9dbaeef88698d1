"""Boxes: canonical corners, exact oriented-box IoU and closed-form axis-aligned IoU.

A box is (R, t, size): `R` (3, 3) rotation from the box frame to the reference frame, `t` (3,) the box
centre in the reference frame [m], `size` (3,) full extents along the box axes [m]. The box frame has its
origin at the box centre, so the box is the set {R p + t : |p_i| <= size_i / 2}.

Corner order (NOCS's `get_3d_bbox` order, so corner lists are comparable with published code): corner `i`
has sign (sx, sy, sz) with sy = - if bit 2 of i is set, sx = - if bit 1 is set, sz = - if bit 0 is set::

          y (up)
          |
      2 ------- 0          top face    (+y): 0 1 2 3
      |\\        |\\         bottom face (-y): 4 5 6 7
      | 3 ------- 1        +x face: 0 1 4 5      -x face: 2 3 6 7
      6 |-------4 |        +z face: 0 2 4 6      -z face: 1 3 5 7
       \\|        \\|
        7 ------- 5 --- x
         \
          z (towards the viewer in this sketch: 0, 2, 4, 6 are the +z corners)

The oriented IoU is exact: the intersection of two boxes is a convex polytope whose every vertex is the
meeting point of three of the twelve face planes, i.e. a corner of one box inside the other, or a point where
an edge of one box crosses a face of the other. Those points are collected in closed form and
scipy's ConvexHull (Qhull) gives the volume. No sampling is involved.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import as_rotation
from prompose_grasp.geometry.tolerances import BOX_FLAT_RTOL, BOX_INSIDE_RTOL

__all__ = [
    "BOX_CORNER_SIGNS",
    "BOX_EDGES",
    "aligned_box_iou",
    "box_corners",
    "oriented_box_intersection_volume",
    "oriented_box_iou",
]

#: (8, 3) signs of the corners in the order documented above (NOCS order).
BOX_CORNER_SIGNS = np.array(
    [[1 - 2 * ((i >> 1) & 1), 1 - 2 * ((i >> 2) & 1), 1 - 2 * (i & 1)] for i in range(8)], dtype=np.float64
)
BOX_CORNER_SIGNS.setflags(write=False)

#: (12, 2) corner index pairs of the box edges: corners whose signs differ in exactly one axis.
BOX_EDGES = np.array([(i, i | bit) for bit in (1, 2, 4) for i in range(8) if not i & bit], dtype=np.intp)
BOX_EDGES.setflags(write=False)


def _vector3(x: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (3,):
        raise InvalidInputError(f"{name} must have shape (3,), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} must be finite, got {a}")
    return a


def _size(x: ArrayLike, name: str) -> np.ndarray:
    a = _vector3(x, name)
    if np.any(a <= 0.0):
        raise InvalidInputError(f"{name} must be > 0 along every axis (full extents in metres), got {a}")
    return a


def box_corners(size: ArrayLike) -> np.ndarray:
    """(8, 3) float64 corners [m] of a box of full extents `size` (3,) [m], centred at the origin of its own
    frame, in the order documented in this module (NOCS order: top face +y first)."""
    return BOX_CORNER_SIGNS * (0.5 * _size(size, "size"))


def _edge_face_crossings(corners: np.ndarray, half: np.ndarray, tol: float) -> np.ndarray:
    """Points where the 12 edges of a box (its `corners` (8, 3) in the frame of an axis-aligned box of half
    extents `half` (3,)) cross the faces of that box and lie on the face (within `tol`). Returns (M, 3)."""
    p0 = corners[BOX_EDGES[:, 0]]  # (12, 3)
    d = corners[BOX_EDGES[:, 1]] - p0  # (12, 3)
    planes = np.stack([-half, half], axis=-1)  # (3, 2): the face coordinates along each axis
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (planes[None, :, :] - p0[:, :, None]) / d[:, :, None]  # (12, 3 axes, 2 signs)
    ok = np.isfinite(lam) & (lam >= 0.0) & (lam <= 1.0)
    e, k, s = np.nonzero(ok)
    pts = p0[e] + lam[e, k, s][:, None] * d[e]
    # On the plane of axis k by construction; pin it there and check the two other coordinates.
    pts[np.arange(len(k)), k] = planes[k, s]
    inside = np.all(np.abs(pts) <= half + tol, axis=1)
    return pts[inside]


def _polytope_volume(points: np.ndarray, scale: float) -> float:
    """Volume [m^3] of the convex hull of (M, 3) points; 0 when they are too few or flat (touching boxes)."""
    if len(points) < 4:
        return 0.0
    centred = points - points.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[-1] <= BOX_FLAT_RTOL * scale * np.sqrt(len(points)):
        return 0.0
    try:
        return float(ConvexHull(points).volume)
    except QhullError:  # a sliver Qhull cannot resolve has no measurable volume
        return 0.0


def oriented_box_intersection_volume(
    R_a: ArrayLike, t_a: ArrayLike, size_a: ArrayLike, R_b: ArrayLike, t_b: ArrayLike, size_b: ArrayLike
) -> float:
    """Exact volume [m^3] of the intersection of two oriented boxes.

    Each box is `R` (3, 3) box-to-reference rotation, `t` (3,) centre [m], `size` (3,) full extents [m], both
    boxes in the same reference frame. Disjoint or merely touching boxes give 0.0.
    """
    R_a = as_rotation(R_a, "R_a")
    R_b = as_rotation(R_b, "R_b")
    t_a, t_b = _vector3(t_a, "t_a"), _vector3(t_b, "t_b")
    size_a, size_b = _size(size_a, "size_a"), _size(size_b, "size_b")
    half_a, half_b = 0.5 * size_a, 0.5 * size_b

    # Bounding spheres apart: nothing to intersect.
    if np.linalg.norm(t_a - t_b) > np.linalg.norm(half_a) + np.linalg.norm(half_b):
        return 0.0

    scale = float(max(size_a.max(), size_b.max()))
    tol = BOX_INSIDE_RTOL * scale

    # Work in b's frame: T_b_a maps a's box frame into b's box frame.
    R_ba = R_b.T @ R_a
    t_ba = R_b.T @ (t_a - t_b)
    corners_a_in_b = BOX_CORNER_SIGNS * half_a @ R_ba.T + t_ba
    corners_b_in_a = (BOX_CORNER_SIGNS * half_b - t_ba) @ R_ba  # R_ab = R_ba^T, applied as row @ R_ba

    parts_in_b = [
        corners_a_in_b[np.all(np.abs(corners_a_in_b) <= half_b + tol, axis=1)],
        _edge_face_crossings(corners_a_in_b, half_b, tol),
    ]
    parts_in_a = [
        corners_b_in_a[np.all(np.abs(corners_b_in_a) <= half_a + tol, axis=1)],
        _edge_face_crossings(corners_b_in_a, half_a, tol),
    ]
    points_in_a = np.concatenate(parts_in_a)
    points = np.concatenate([*parts_in_b, points_in_a @ R_ba.T + t_ba])
    volume = _polytope_volume(points, scale)
    return float(min(volume, np.prod(size_a), np.prod(size_b)))


def oriented_box_iou(
    R_a: ArrayLike, t_a: ArrayLike, size_a: ArrayLike, R_b: ArrayLike, t_b: ArrayLike, size_b: ArrayLike
) -> float:
    """Exact 3D IoU in [0, 1] of two oriented boxes in a common reference frame.

    Args:
        R_a, R_b: (3, 3) rotations from each box frame to the reference frame (e.g. `R_cam_obj`).
        t_a, t_b: (3,) box centres in the reference frame [m].
        size_a, size_b: (3,) full extents along each box's own axes [m], all > 0.
    Returns:
        intersection volume / union volume; 0.0 for disjoint or touching boxes, 1.0 for identical ones.
    """
    inter = oriented_box_intersection_volume(R_a, t_a, size_a, R_b, t_b, size_b)
    vol_a = float(np.prod(np.asarray(size_a, dtype=np.float64)))
    vol_b = float(np.prod(np.asarray(size_b, dtype=np.float64)))
    union = vol_a + vol_b - inter
    return float(np.clip(inter / union, 0.0, 1.0))


def aligned_box_iou(min_a: ArrayLike, max_a: ArrayLike, min_b: ArrayLike, max_b: ArrayLike) -> float:
    """Closed-form IoU in [0, 1] of two axis-aligned boxes given by their (3,) min and max corners [m].

    Each box needs max > min on every axis. Boxes that only touch give 0.0.
    """
    lo_a, hi_a = _vector3(min_a, "min_a"), _vector3(max_a, "max_a")
    lo_b, hi_b = _vector3(min_b, "min_b"), _vector3(max_b, "max_b")
    for lo, hi, name in ((lo_a, hi_a, "a"), (lo_b, hi_b, "b")):
        if np.any(hi <= lo):
            raise InvalidInputError(f"box {name} needs max > min on every axis, got min {lo} and max {hi}")
    overlap = np.clip(np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b), 0.0, None)
    inter = float(np.prod(overlap))
    union = float(np.prod(hi_a - lo_a) + np.prod(hi_b - lo_b)) - inter
    return float(np.clip(inter / union, 0.0, 1.0))
