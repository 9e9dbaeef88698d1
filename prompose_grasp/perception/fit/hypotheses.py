"""Initial hypotheses of the fit: rotations, and for each the amodal initial box.

With a support-plane normal `up_cam` the object's +y is up and only the yaw is unknown: yaws spaced evenly
from the principal direction of the points projected on the plane (8 for asymmetric shapes, 4 for two-fold
ones, 1 for shapes round about y, tried at three section widths). Without it, the 24 proper rotations that
map the object axes onto the signed, permuted PCA axes (6 when only the y axis matters). A warm start is
the single hypothesis. The initial box (`_initial_state`): extents of the points in the hypothesis frame
are lower bounds (one side is seen); the prior's metric aspect ratios fill the unseen depth, the box grows
away from the camera, and with a support plane the bottom face sits on the plane.
"""

from __future__ import annotations

import math

import numpy as np

from prompose_grasp.geometry.occlusion import cut_ends
from prompose_grasp.geometry.pointcloud import robust_descriptor
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.fit.problem import _plane_basis, _State
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.prior import ShapePrior

#: Number of yaw hypotheses about the support normal, per symmetry tag.
_YAWS = {"none": 8, "box": 4, "y_2fold": 8, "x_continuous": 4, "y_continuous": 1, "spherical": 1}

#: Width factors of the initial section of round shapes (one hypothesis each, see `_initial_states`).
_ROUND_WIDTHS = (1.0, 1.15, 1.3)

#: The image border or an occluder cuts off a side of the box when at least this share of the points at that
#: end of the box axis (its outer 2 %, beyond the percentiles of the seen extents) lie on such a cut edge
#: (`_cut_sides`): where the cut crosses the object's end, the farthest points along the axis are the cut's;
#: at a free end they are the object's own silhouette.
_CUT_SHARE = 0.5


def _R_from_yaw(up: np.ndarray, e1: np.ndarray, e2: np.ndarray, yaw: float) -> np.ndarray:
    x = math.cos(yaw) * e1 + math.sin(yaw) * e2
    z = np.cross(x, up)
    return np.column_stack([x, up, z])


def _proper_axis_rotations(U: np.ndarray, symmetry: str) -> list[np.ndarray]:
    """Rotations whose columns are signed, permuted columns of the PCA frame `U` (24 proper ones)."""
    out = []
    seen_y = set()
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for sx in (1.0, -1.0):
            for sy in (1.0, -1.0):
                for sz in (1.0, -1.0):
                    R = U[:, perm] * np.array([sx, sy, sz])
                    if np.linalg.det(R) < 0.0:
                        continue
                    if symmetry in ("y_continuous", "spherical"):
                        key = (perm[1], sy)
                        if key in seen_y:
                            continue
                        seen_y.add(key)
                    out.append(R)
    return out


def _cut_sides(local: np.ndarray, lo: np.ndarray, hi: np.ndarray, cut_edge: np.ndarray) -> np.ndarray:
    """(3, 2) bool: which sides (low, high) of each box axis the image border or an occluder cuts off
    (`geometry.occlusion.cut_ends` with `_CUT_SHARE`), from the points in box axes `local` (N, 3), their 2nd
    and 98th percentiles `lo`, `hi` (3,) and which of them lie on a cut edge (`cut_edge`, (N,))."""
    return cut_ends(local, lo, hi, cut_edge, _CUT_SHARE)


def _initial_state(
    pts: np.ndarray,
    R: np.ndarray,
    prior: ShapePrior,
    up: np.ndarray | None,
    plane: tuple[np.ndarray, float] | None,
    symmetry: str,
    widen: float = 1.0,
    cut_edge: np.ndarray | None = None,
) -> _State:
    """Amodal initial box for the rotation `R`: visible extents as lower bounds, prior aspect for the rest,
    grown away from the camera; bottom on the plane when one is given.

    `cut_edge` (N,) marks the points on the image border (`_on_border`) or an occluder's edge
    (`_next_to_occluder`): a side they cut off (`_cut_sides`) is not seen where it ends, so its axis takes
    its size from the prior's aspect scaled to the uncut axes, and the box grows across the cut there (the
    fit cannot tell: the prior's points beyond the image or behind the occluder do not pull)."""
    local = pts @ R  # object-axis coordinates of the points (origin at the camera)
    lo = np.percentile(local, 2.0, axis=0)
    hi = np.percentile(local, 98.0, axis=0)
    ext = np.maximum(hi - lo, 1e-3)
    cut = np.zeros((3, 2), dtype=bool) if cut_edge is None else _cut_sides(local, lo, hi, cut_edge)
    if plane is not None:
        normal, d = plane
        heights = pts @ normal + d
        top = float(np.percentile(heights, 98.0))
        ext[1] = max(top, 1e-3)
        cut[1, 0] = False  # the bottom rests on the plane, seen or not
    aspect = prior.aspect
    axis_cut = cut[:, 0] | cut[:, 1]  # (3,) bool: either side of the axis cut off
    if symmetry in ("y_continuous", "spherical"):
        ext[0] = ext[2] = max(ext[0], ext[2])
        axis_cut[[0, 2]] = axis_cut[0] or axis_cut[2]  # one section width
    # Scale of the prior's aspect that just covers the seen extents along the best-seen axes: the two best of
    # an uncut box, and of a cut one its best uncut axis (besides the cut one, the third is the depth
    # direction, seen shorter: an occluded mug seen as a sliver took its width from its depth). An axis seen
    # shorter than that is grown to it, a cut one to the aspect itself.
    ratio = ext / aspect
    free = np.sort(ratio[~axis_cut]) if not axis_cut.all() else np.sort(ratio)
    kappa = float(free[-1] if axis_cut.any() else free[1])
    size = np.maximum(ext, kappa * aspect * np.where(axis_cut, 1.0, 0.9))
    if symmetry in ("y_continuous", "spherical"):
        size[0] = size[2] = max(size[0], size[2])
    size[[0, 2]] *= widen
    centre_local = 0.5 * (lo + hi)
    # grow the box away from the camera (the seen face stays where it is), or across the cut
    view = pts.mean(axis=0) @ R  # camera -> object direction in object axes (unnormalised)
    direction = np.where(cut[:, 0] | cut[:, 1], cut[:, 1].astype(float) - cut[:, 0], np.sign(view))
    grow = size - ext
    centre_local = centre_local + 0.5 * grow * direction
    centre = R @ centre_local
    if plane is not None:
        normal, d = plane
        if not cut[1, 1]:
            size[1] = ext[1]
        bottom = centre - (centre @ normal + d) * normal
        return _State(R.copy(), bottom, np.log(size))
    return _State(R.copy(), centre, np.log(size))


def _initial_rotations(
    pts: np.ndarray, up: np.ndarray | None, symmetry: str, cfg: FitConfig
) -> list[np.ndarray]:
    """The rotation hypotheses of a cold start for the gated points `pts` (N, 3) (module docstring)."""
    desc = robust_descriptor(pts, *cfg.clip_percentiles)
    if up is None:
        return _proper_axis_rotations(np.asarray(desc.axes), symmetry)
    e1, e2 = _plane_basis(up)
    c = pts - desc.centroid
    uv = np.column_stack([c @ e1, c @ e2])
    w, V = np.linalg.eigh(uv.T @ uv)
    major = V[:, int(np.argmax(w))]
    phi = math.atan2(major[1], major[0])
    n_yaw = _YAWS[symmetry]
    if symmetry in ("box", "x_continuous"):  # two-fold: yaw in [0, pi) suffices
        return [_R_from_yaw(up, e1, e2, phi + math.pi * k / n_yaw) for k in range(n_yaw)]
    return [_R_from_yaw(up, e1, e2, phi + 2.0 * math.pi * k / n_yaw) for k in range(n_yaw)]


def _initial_states(
    pts: np.ndarray,
    rotations: list[np.ndarray],
    prior: ShapePrior,
    up: np.ndarray | None,
    plane: tuple[np.ndarray, float] | None,
    cut_edge: np.ndarray | None,
) -> list[_State]:
    """The amodal initial box of each rotation hypothesis. A round shape has one rotation hypothesis; its
    section is tried at a few widths instead, since a narrower section closer to the camera is a local
    minimum of the visible-arc fit."""
    symmetry = prior.symmetry
    widths = _ROUND_WIDTHS if symmetry in ("y_continuous", "spherical") and up is not None else (1.0,)
    return [
        _initial_state(pts, R, prior, up, plane, symmetry, w, cut_edge) for R in rotations for w in widths
    ]


def _warm_state(init: Pose9D, up: np.ndarray | None, plane: tuple[np.ndarray, float] | None) -> _State:
    """The single hypothesis of a warm start: `init`, made upright about `up` (its yaw kept) when given,
    its bottom moved onto the plane when one is given."""
    R0 = init.R
    if up is not None:
        e1, e2 = _plane_basis(up)
        x0 = R0[:, 0] - (R0[:, 0] @ up) * up
        if np.linalg.norm(x0) < 1e-6:
            x0 = e1
        yaw = math.atan2(float(x0 @ e2), float(x0 @ e1))
        R0 = _R_from_yaw(up, e1, e2, yaw)
    size0 = np.asarray(init.size, dtype=np.float64)
    if plane is not None:
        assert up is not None  # a plane's normal is the up direction (`_check_inputs`)
        bottom = init.t - 0.5 * size0[1] * up
        bottom = bottom - (bottom @ plane[0] + plane[1]) * plane[0]
        return _State(R0.copy(), bottom, np.log(size0))
    return _State(R0.copy(), init.t.copy(), np.log(size0))
