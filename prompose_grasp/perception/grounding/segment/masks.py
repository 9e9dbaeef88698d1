"""Full-resolution masks of the grid's segments (`_paint_segments`): each segment's cells above the plane,
grown by the grid spacing into above-plane pixels, plus pixels without depth (occlusion shadows, holes)
around it whose colour matches it, plus an inner floor the height cut removed (`_inner_floor`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from prompose_grasp.perception.grounding.plane import PlaneFrame
from prompose_grasp.perception.grounding.segment.cells import _above, _colour_distance, _height_cut, lab_image
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

#: Pixels without depth join a segment when their Lab colour is within this many `colour_edge` of the
#: segment's median (shading over an object spans more than one neighbour-to-neighbour edge).
_FILL_COLOUR_FACTOR = 2.0

#: An inner floor pixel (`_inner_floor`) may read this many sigma(z) below the plane (noise), not more: a
#: pixel far below the plane is something else seen through a gap.
_INNER_FLOOR_SIGMAS = 3.0

#: ... and lie within this distance [m] of the object's footprint (`_inner_floor`). The footprint is the hull
#: of the points above the height cut; a floor seen right up to a thin rim's edge at a slant lies beyond the
#: rim's own points by its parallax (`test_inner_floor_of_a_tray_joins_its_walls`: a 4 cm rim needs ~2 cm).
#: Dev split seed 22, grounded masks' precision / recall: laptops 0.949 / 0.938 (no footprint test) ->
#: 0.986 / 0.935 (0 cm) -> 0.981 / 0.938 (2 cm), mugs 0.951 / 0.923 -> 0.962 / 0.918 -> 0.959 / 0.923.
_FLOOR_FOOTPRINT_MARGIN_M = 0.02

#: Without a support plane, segments bigger than this share of the valid pixels are background (walls, floor).
_MAX_BACKGROUND_SHARE = 0.25


@dataclass(frozen=True)
class Segment:
    """One object candidate.

    Attributes:
        mask: (H, W) bool full-resolution mask.
        points_cam: (N, 3) float64 camera-frame points [m] of the grid cells the segment was clustered
            from, with depth (not of the fragments it gathered, `_attach_fragments`, which are in `mask`).
        box_xyxy: (4,) int64 (x0, y0, x1, y1), inclusive.
        base_height_m: height [m] above the support plane of the surface it stands on: 0 on the plane, the
            top face of the object under it for one standing on another (`stacks._split_stacked`).
    """

    mask: np.ndarray
    points_cam: np.ndarray
    box_xyxy: np.ndarray
    base_height_m: float = 0.0


class _GridLabels(NamedTuple):
    """The grid's segments, (h, w) each: `labels` 0..K-1 (-1: none), cells of fragments a segment gathered
    (`fragment`: in its mask, not in its points), cells of objects lying flat (`flat`: their pixels count
    though under the height cut), background cells no mask may grow into (`background`), and per label
    the height above the support of the surface it stands on (`base_m`, (K,))."""

    labels: np.ndarray
    fragment: np.ndarray
    flat: np.ndarray
    background: np.ndarray
    base_m: np.ndarray


#: Gaps in a rim's mask up to about this many pixels are bridged when asking what it encloses (`_enclosed`):
#: the sensor drops a 2 px band on each side of a depth jump, and the mask's colour fill closes most of it.
_ENCLOSE_CLOSING_PX = 9


def _enclosed(mask: np.ndarray, base_band_px: int) -> np.ndarray:
    """(H, W) bool: pixels off `mask` that it surrounds (bridging gaps of up to `_ENCLOSE_CLOSING_PX`), or
    that lie within `base_band_px` of it (an object's own base under the height cut): the inside of a
    ring, not the table between a clamp's open jaws, which reaches the image region's edge."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_ENCLOSE_CLOSING_PX, _ENCLOSE_CLOSING_PX))
    closed = cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_CLOSE, k)
    _, comp = cv2.connectedComponents((closed == 0).view(np.uint8), connectivity=4)
    outer = np.unique(np.concatenate([comp[0], comp[-1], comp[:, 0], comp[:, -1]]))
    band = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * base_band_px + 1, 2 * base_band_px + 1))
    near = cv2.dilate(mask.view(np.uint8), band) > 0
    surrounded = (closed == 0) & ~np.isin(comp, outer)
    return (near & ~mask) | surrounded


def _inner_floor(
    mask: np.ndarray,
    points: np.ndarray,
    lab: np.ndarray,
    ref_lab: np.ndarray,
    plane: SupportPlane,
    config: GroundingConfig,
    f_px: float,
) -> np.ndarray:
    """Pixels of an object's inner floor that the height cut removed (see `_INNER_FLOOR_SIGMAS`).

    Within the mask's convex outline in the image, pixels with depth that lie on or just above the plane
    (below the height cut), that the mask encloses or that lie within its base band (`_enclosed`: a bowl's
    floor lies inside its rim, the table between a clamp's open jaws does not) and have the segment's colour
    (within one `colour_edge`) belong to it when they also lie inside the object's footprint on the plane
    (the convex hull of its points above the cut, seen from above): the inside bottom of a bowl or a mug
    stands only millimetres above the table, within the wall. The image outline alone also takes in the
    table beside a laptop's base or a camera's lens, just as low and, for a dark object on a dark table, of
    its colour too (dev split seed 22: laptop masks up to 20 % table, boxes 1.3-1.6x too wide); that table
    lies outside the object's footprint. `f_px`: the focal length [px] (the base band's width).
    """
    contours, _ = cv2.findContours(mask.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = cv2.convexHull(np.concatenate(contours))  # the outline's points suffice (10x fewer than pixels)
    inside = np.zeros(mask.shape, dtype=np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    z = points[..., 2]
    with np.errstate(invalid="ignore"):
        h = points @ plane.normal_cam + plane.offset_m
        low = np.isfinite(z) & (h > -_INNER_FLOOR_SIGMAS * config.sigma_m(z))
    same = _colour_distance(lab, ref_lab) < config.colour_edge
    floor = inside.view(bool) & low & same & ~mask
    seen = z[mask][np.isfinite(z[mask])]
    if not floor.any() or len(seen) == 0:  # no depth on the object: no footprint to hold a floor
        return np.zeros_like(mask)
    # the object's own base under the height cut spans the cut's height in the image: f cut / z pixels
    z_obj = float(np.median(seen))
    floor &= _enclosed(mask, int(np.ceil(f_px * float(_height_cut(np.asarray(z_obj), config)) / z_obj)))
    if not floor.any():
        return floor
    # the footprint: the body's points seen from above, in the plane's (right, forward) coordinates
    frame = PlaneFrame(plane)
    body = frame.coords(points[mask & _above(points, plane, config)])[:, :2]
    try:
        edges = ConvexHull(body).equations  # a x + b y + c <= 0 inside, (a, b) unit
    except (QhullError, ValueError):  # fewer than 3 points, or all on a line: no area to hold a floor
        return np.zeros_like(floor)
    rows, cols = np.nonzero(floor)
    xy = frame.coords(points[rows, cols])[:, :2]
    within = np.all(xy @ edges[:, :2].T + edges[:, 2] <= _FLOOR_FOOTPRINT_MARGIN_M, axis=1)
    floor[rows[~within], cols[~within]] = False
    return floor


def _paint_segments(
    rgb: np.ndarray,
    point_map: np.ndarray,
    Pg: np.ndarray,
    lab_g: np.ndarray,
    grid: _GridLabels,
    plane: SupportPlane | None,
    config: GroundingConfig,
    support_hull: np.ndarray | None,
    plane_coords: Callable[[np.ndarray], np.ndarray] | None,
    f_px: float,
) -> list[Segment]:
    """The `Segment` of each grid segment (`segment_objects`' arguments; `Pg` (h, w, 3) the grid's points,
    `lab_g` (h, w, 3) its Lab colours), in label order. Masks never overlap: a pixel goes to the first
    segment that takes it. Left out: without a plane a segment bigger than `_MAX_BACKGROUND_SHARE` of the
    valid cells; one whose footprint centre lies off `support_hull` by more than 5 cm; a mask smaller than
    `min_segment_px`."""
    labels, fragment, flat, background, base_m = grid
    H, W = point_map.shape[:2]
    h, w = Pg.shape[:2]
    s = config.segment_stride_px
    K = int(labels.max()) + 1
    rows = np.minimum(np.arange(H) // s, h - 1)
    cols = np.minimum(np.arange(W) // s, w - 1)
    lab_full = labels[np.ix_(rows, cols)]
    flat_full = flat[np.ix_(rows, cols)] & np.isfinite(point_map[..., 2])
    background_full = background[np.ix_(rows, cols)]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * s + 1, 2 * s + 1))
    close_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9))
    total_valid = max(1, int(np.isfinite(Pg[..., 2]).sum()))
    pad = 2 * s + 5

    taken = np.zeros((H, W), dtype=bool)  # pixels already given to a segment: masks never overlap
    segments: list[Segment] = []
    for k in range(K):
        vv, uu = np.nonzero(labels == k)
        if plane is None and len(vv) > _MAX_BACKGROUND_SHARE * total_valid:
            continue
        body = ~fragment[vv, uu]
        pts = Pg[vv[body], uu[body]] if np.any(body) else Pg[vv, uu]
        pts = pts[np.isfinite(pts[:, 2])]
        if support_hull is not None and plane_coords is not None and len(pts):
            centre = plane_coords(pts)[:, :2].mean(axis=0)
            inside = cv2.pointPolygonTest(support_hull, (float(centre[0]), float(centre[1])), True)
            if inside < -0.05:  # 5 cm: the centre of an object overhanging the edge still counts
                continue
        y0, y1 = max(0, vv.min() * s - pad), min(H, (vv.max() + 1) * s + pad)
        x0, x1 = max(0, uu.min() * s - pad), min(W, (uu.max() + 1) * s + pad)
        roi_lab = lab_full[y0:y1, x0:x1]
        own = roi_lab == k
        roi_points = point_map[y0:y1, x0:x1]
        above = _above(roi_points, plane, config)
        invalid = ~np.isfinite(roi_points[..., 2])
        others = ((roi_lab >= 0) & ~own) | taken[y0:y1, x0:x1] | background_full[y0:y1, x0:x1]
        # a flat object's cells are its pixels, though most of them are under the cut one by one
        seed = own & (above | flat_full[y0:y1, x0:x1])
        grown = cv2.dilate(seed.view(np.uint8), kernel).view(bool) & above & ~others
        mask = seed | grown
        # pixels without depth around and inside the segment: keep those of the segment's colour
        lab_roi = lab_image(rgb[y0:y1, x0:x1])
        ref = np.median(lab_roi[mask], axis=0) if mask.any() else np.median(lab_g[vv, uu], axis=0)
        near = _colour_distance(lab_roi, ref) < _FILL_COLOUR_FACTOR * config.colour_edge
        closed = cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_CLOSE, close_kernel).view(bool)
        grown_inv = cv2.dilate(mask.view(np.uint8), kernel).view(bool)
        mask |= (closed | grown_inv) & invalid & near & ~others
        if plane is not None and mask.any():
            mask |= _inner_floor(mask, roi_points, lab_roi, ref, plane, config, f_px) & ~others
        mask &= ~taken[y0:y1, x0:x1]
        if mask.sum() < config.min_segment_px:
            continue
        full = np.zeros((H, W), dtype=bool)
        full[y0:y1, x0:x1] = mask
        taken[y0:y1, x0:x1] |= mask
        my, mx = np.nonzero(mask)
        box = np.array([x0 + mx.min(), y0 + my.min(), x0 + mx.max(), y0 + my.max()], dtype=np.int64)
        segments.append(Segment(mask=full, points_cam=pts, box_xyxy=box, base_height_m=float(base_m[k])))
    return segments
