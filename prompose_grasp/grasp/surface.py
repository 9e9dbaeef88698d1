"""Parallel-jaw grasps on the seen surface: top-down across a narrow part of an object wider than the stroke.

The box and mesh grasps (`parallel_jaw`) close across the estimated box or the scaled prior. An object whose
box is wider than the stroke on both footprint axes (a frying pan, a toy aeroplane, a hammer lying flat)
has no such grasp, although a part of it (a handle, a wing, a rim, a neck) would fit between the jaws, and
a prior of another shape says nothing about where that part is. The seen surface does.

`section_grasps` turns the object's seen surface points (`ObjectModel.surface_points`) into a height map on
the support plane: per cell of `_CELL_M`, the highest point above the plane. The camera sees the object's
top and one side, and a top-down grasp's fingers sweep whole columns, so the top surface is what decides
where they can go. Gaps of one cell (the sampling of a far surface) are closed. For sample centres on the
object (every `_SPACING_M`) and `_DIRECTIONS` closing directions:

- the finger bottom goes to `pad length - fingertip_contact_margin_m` below the local top, never lower
  than `support_clearance_m` above the plane (a low object is held by the fingertips);
- along the closing line (over the pad's width) the cells higher than the finger bottom around the centre
  form the section; it must fit the stroke with `min_clearance_m` each side, both its ends must reach
  `fingertip_contact_margin_m` above the finger bottom (the pads touch it), and the columns the open
  fingers sweep down must be lower than the finger bottom;
- everything under the palm (the housing's footprint) stays `palm_clearance_m` below it.

Quality: 0.4 top-down (every section grasp is), 0.3 centring (the grasp centre's distance from the centre
of the volume under the height map, against the footprint's half diagonal: a handle far from the centre of
mass holds a torque), 0.2 depth (pad overlap with the section's ends), 0.1 width margin; less
`_UNSEEN_PENALTY`, since the far side of a section is hidden from the camera and may be wider than seen.
The target itself is not collision-checked for these candidates (its box or prior is what they do not
trust); the height map check stands in for it, other objects and fixtures are checked as usual.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import grey_closing

from prompose_grasp.geometry.distance import cross
from prompose_grasp.grasp.candidates import Candidates, Reasons, stack_transforms
from prompose_grasp.grasp.grippers import ParallelJawGeometry
from prompose_grasp.grasp.types import GraspConfig, ObjectModel, Plane

__all__ = ["needs_sections", "section_grasps"]

#: Height-map cell [m]: a 640 x 480 camera samples a surface 1 m away every ~1.7 mm, so a cell holds a few
#: points; the cell grows to the points' own spacing on a far or subsampled surface.
_CELL_M = 0.004
#: Sample centres on the object this far apart [m] and closing directions over half a turn.
_SPACING_M = 0.01
_DIRECTIONS = 8
#: Points this high above the plane are the object's (the plane's own noise is ~1 mm at 1 m) [m].
_MIN_HEIGHT_M = 0.004
#: A part of the seen surface: its far side is hidden, so it ranks below a model grasp with the same terms.
_UNSEEN_PENALTY = 0.1
#: Candidates kept (best first, one per tcp cell of `_DISTINCT_M` and direction): the rest are near repeats
#: of the same placement, and the planner's checks should see every part of the object.
_MAX_SECTIONS = 80
_DISTINCT_M = 0.015
_SEEN_MIN_POINTS = 20


def needs_sections(target: ObjectModel, gripper: ParallelJawGeometry, config: GraspConfig) -> bool:
    """True when the jaws cannot close across the target's box along either of its footprint axes (both
    wider than the stroke less twice `min_clearance_m`) and its seen surface is known."""
    if target.surface_points is None or len(target.surface_points) < _SEEN_MIN_POINTS:
        return False
    size = np.asarray(target.pose.size, dtype=np.float64)
    footprint = np.delete(size, 1)  # object +y is its up: x and z span the footprint
    return bool(np.min(footprint) + 2.0 * config.min_clearance_m > gripper.stroke_m)


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane with normal `normal` (right-handed with it)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ normal) * normal
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def _runs(blocked: np.ndarray, mid: int) -> tuple[np.ndarray, np.ndarray]:
    """(..., S) bool samples along lines -> (...,) number of consecutive blocked samples from `mid` outwards
    on each side (`mid` itself counted on both)."""
    right = np.cumprod(blocked[..., mid:], axis=-1).sum(axis=-1)
    left = np.cumprod(blocked[..., mid::-1], axis=-1).sum(axis=-1)
    return left, right


def section_grasps(
    target: ObjectModel, gripper: ParallelJawGeometry, config: GraspConfig, support: Plane | None
) -> Candidates:
    """Top-down jaw grasps across narrow parts of the target's seen surface (module docstring); empty without
    a support plane or surface points."""
    if support is None or target.surface_points is None or len(target.surface_points) < _SEEN_MIN_POINTS:
        return Candidates.empty()
    n = np.asarray(support.normal, dtype=np.float64)
    pts = np.asarray(target.surface_points, dtype=np.float64)
    h = support.height(pts)
    pts, h = pts[h > _MIN_HEIGHT_M], h[h > _MIN_HEIGHT_M]
    if len(pts) < _SEEN_MIN_POINTS:
        return Candidates.empty()
    e1, e2 = _plane_axes(n)
    uv = np.stack([pts @ e1, pts @ e2], axis=1)
    spacing = float(np.median(np.linalg.norm(np.diff(np.sort(uv, axis=0), axis=0), axis=1)))
    cell = max(_CELL_M, 1.2 * spacing)
    pad_w, pad_t, pad_l = (float(v) for v in gripper.pad_size_m)
    stroke = float(gripper.stroke_m)
    finger_t = pad_t + float(gripper.finger_thickness_m)  # pad and the plate behind it, along the closing
    finger_w = pad_w + 2.0 * float(gripper.finger_width_margin_m)
    reach = stroke + finger_t + cell  # along a closing line, either side of the centre
    house_x, house_y = float(gripper.housing_half_m[0]), float(gripper.housing_half_m[1])
    border = max(reach, math.hypot(house_x, house_y)) + cell
    lo = uv.min(axis=0) - border
    shape = np.ceil((uv.max(axis=0) + border - lo) / cell).astype(int) + 1
    H = np.zeros(tuple(shape))
    ij = np.floor((uv - lo) / cell).astype(int)
    np.maximum.at(H, (ij[:, 0], ij[:, 1]), h)
    H = grey_closing(H, size=3)  # a cell between seen ones is the same surface, not a gap between parts

    def heights(p_uv: np.ndarray) -> np.ndarray:
        k = np.floor((p_uv - lo) / cell).astype(int)
        inside = np.all((k >= 0) & (k < shape), axis=-1)
        k = np.clip(k, 0, shape - 1)
        return np.where(inside, H[k[..., 0], k[..., 1]], 0.0)

    occupied = np.argwhere(H > _MIN_HEIGHT_M)
    step = max(1, round(_SPACING_M / cell))
    occupied = occupied[(occupied[:, 0] % step == 0) & (occupied[:, 1] % step == 0)]
    if len(occupied) == 0:
        return Candidates.empty()
    centres = lo + (occupied + 0.5) * cell  # (C, 2)
    theta = np.arange(_DIRECTIONS) * math.pi / _DIRECTIONS
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # (K, 2) closing directions
    o = np.stack([-d[:, 1], d[:, 0]], axis=1)  # (K, 2) along the pads' width
    s = np.arange(-reach, reach + 1e-9, cell)  # (S,) along the closing line, a sample per cell
    mid = int(np.argmin(np.abs(s)))
    across = np.linspace(-0.5 * finger_w, 0.5 * finger_w, 3)  # (J,) over the finger's width
    P = heights(
        centres[:, None, None, None, :]
        + s[None, None, None, :, None] * d[None, :, None, None, :]
        + across[None, None, :, None, None] * o[None, :, None, None, :]
    ).max(axis=2)  # (C, K, S): the highest cell under the fingers' width at each point of the line
    top = P[:, :, mid]
    margin = config.fingertip_contact_margin_m
    z_b = np.maximum(config.support_clearance_m, top - (pad_l - margin))  # (C, K) finger bottom
    blocked = P > z_b[..., None]
    left, right = _runs(blocked, mid)
    i_lo, i_hi = mid - left + 1, mid + right - 1  # the section's end samples
    inside_line = (i_lo > 0) & (i_hi < len(s) - 1)
    half_cell = 0.5 * cell
    s_lo, s_hi = s[np.clip(i_lo, 0, len(s) - 1)] - half_cell, s[np.clip(i_hi, 0, len(s) - 1)] + half_cell
    width = s_hi - s_lo
    ok = inside_line & (left > 0) & (width + 2.0 * config.min_clearance_m <= stroke)
    opening = np.minimum(stroke, width + 2.0 * config.clearance_m)
    s_mid = 0.5 * (s_lo + s_hi)
    # the columns the open fingers (and the gap inside them) sweep down: nothing above the finger bottom
    rel = np.abs(s[None, None, :] - s_mid[..., None])
    swept = (rel > 0.5 * width[..., None]) & (rel <= 0.5 * opening[..., None] + finger_t)
    ok &= ~np.any(swept & blocked, axis=-1)
    # both ends touch the pads at least the contact margin above their lower edge
    h_lo = np.take_along_axis(P, np.clip(i_lo, 0, len(s) - 1)[..., None], axis=-1)[..., 0]
    h_hi = np.take_along_axis(P, np.clip(i_hi, 0, len(s) - 1)[..., None], axis=-1)[..., 0]
    h_end = np.minimum(h_lo, h_hi)
    ok &= h_end >= z_b + margin
    c_idx, k_idx = np.nonzero(ok)
    if len(c_idx) == 0:
        return Candidates.empty()
    dk, ok_dir = d[k_idx], o[k_idx]
    centre_uv = centres[c_idx] + s_mid[c_idx, k_idx][:, None] * dk
    zb = z_b[c_idx, k_idx]
    # the palm (the housing's footprint) clear of everything under it
    gx = np.linspace(-house_x, house_x, 5)
    gy = np.linspace(-house_y, house_y, 9)
    under = heights(
        centre_uv[:, None, None, :]
        + gx[None, :, None, None] * ok_dir[:, None, None, :]
        + gy[None, None, :, None] * dk[:, None, None, :]
    ).max(axis=(1, 2))
    palm_ok = under < zb + float(gripper.finger_length_m) - config.palm_clearance_m
    keep = np.flatnonzero(palm_ok)
    if len(keep) == 0:
        return Candidates.empty()
    c_idx, k_idx, centre_uv, zb, dk = c_idx[keep], k_idx[keep], centre_uv[keep], zb[keep], dk[keep]
    w = width[c_idx, k_idx]
    band_top = np.minimum(h_end[c_idx, k_idx], zb + pad_l)

    # quality (module docstring)
    cells = lo + (np.argwhere(H > _MIN_HEIGHT_M) + 0.5) * cell
    vol = H[H > _MIN_HEIGHT_M]
    com = (cells * vol[:, None]).sum(axis=0) / vol.sum()
    half_diag = 0.5 * float(np.linalg.norm(np.ptp(cells, axis=0))) + cell
    off = np.linalg.norm(centre_uv - com, axis=1)
    centring = np.clip(1.0 - off / half_diag, 0.0, 1.0)
    depth = np.clip((band_top - zb) / pad_l, 0.0, 1.0)
    width_margin = np.clip(1.0 - w / stroke, 0.0, 1.0)
    quality = 0.4 + 0.3 * centring + 0.2 * depth + 0.1 * width_margin - _UNSEEN_PENALTY

    # one candidate per tcp cell and direction, best first
    key = np.floor(centre_uv / _DISTINCT_M).astype(np.int64)
    order = np.lexsort((-quality,))
    _, first = np.unique(np.stack([key[order, 0], key[order, 1], k_idx[order]], axis=1), axis=0,
                         return_index=True)  # fmt: skip
    pick = order[np.sort(first)]
    pick = pick[np.argsort(-quality[pick], kind="stable")][:_MAX_SECTIONS]
    m = len(pick)
    offset = float(support.offset_m)

    def to_base(p_uv: np.ndarray, height: np.ndarray) -> np.ndarray:
        return p_uv[:, :1] * e1 + p_uv[:, 1:2] * e2 + (height - offset)[:, None] * n

    closing = dk[pick, :1] * e1 + dk[pick, 1:2] * e2
    approach = np.tile(-n, (m, 1))
    R = np.stack([cross(closing, approach), closing, approach], axis=-1)
    tcp = to_base(centre_uv[pick], zb[pick] + 0.5 * pad_l)
    z_contact = 0.5 * (zb[pick] + margin + band_top[pick])
    half_w = 0.5 * w[pick]
    contacts = np.stack(
        [
            to_base(centre_uv[pick] - half_w[:, None] * dk[pick], z_contact),
            to_base(centre_uv[pick] + half_w[:, None] * dk[pick], z_contact),
        ],
        axis=1,
    )
    widths, offs = w[pick], off[pick]

    def section_reason(row: int) -> str:
        return (
            f"top-down across a {100 * widths[row]:.1f} cm wide part of the seen surface, "
            f"{100 * offs[row]:.1f} cm from its centre"
        )

    return Candidates(
        stack_transforms(R, tcp),
        opening[c_idx, k_idx][pick],
        widths,
        contacts,
        quality[pick],
        np.full(m, "section", dtype=object),
        Reasons.lazy(section_reason, m),
        np.zeros(m, dtype=bool),
        np.full(m, "", dtype=object),
    )
