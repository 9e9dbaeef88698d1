"""Objects standing on other objects (a drill on a lying box, a small carton on a large one): one segment
when their surfaces touch in depth and colour, split at the lower one's top face (`_split_stacked`)."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

#: A grid cell faces up when its surface normal is within this of the support's normal [deg]: the normal
#: from differences 2 cells apart on each side tilts by ~10 deg under a D435's noise at 0.6-1 m.
_UP_MAX_DEG = 20.0

#: The lower object's top face: at least this high above the support [m] (a laptop's base, a plate, a
#: stapler's plate and the wings of a toy aeroplane stay lower: parts of one object) ...
_FACE_MIN_H_M = 0.04
#: ... showing at least this much area [m^2] on the plane beside what stands on it (7 x 4 cm: a lid's rim
#: around its knob, a cap's shoulder around its neck are smaller) ...
_FACE_FREE_AREA_M2 = 0.0028
#: ... measured on a raster of this pitch [m] of the face cells' plane coordinates.
_AREA_PITCH_M = 0.005

#: The object standing on the face rises at least this far above it [m] (a knob, a handle's grip, a label's
#: bump stay lower) ...
_UPPER_MIN_RISE_M = 0.04
#: ... and at least this share of its points lie over the face, `_INSIDE_FACE_M` or more inside the face's
#: outline on the plane: it stands on the face. A carton standing on the table against the lower one's back
#: has its front on the face's back edge and the rest behind it.
_UPPER_OVER_SHARE = 0.6
_INSIDE_FACE_M = 0.01

#: The lower object has walls down to the support under the face's edge: its cells in the lower half of
#: the face's height (a box's sides) lie within `_WALL_BAND_M` of the face's outline on the plane (the
#: wall's own thickness in depth noise), at least this share of them; a shelf or a lid held up by a stem,
#: or a wing on a fuselage, has its low cells under the middle of the face.
_WALL_EDGE_SHARE = 0.6
_WALL_BAND_M = 0.02


def _up_facing(Pg: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(h, w) bool: grid cells whose surface normal (from the neighbours 2 cells away along rows and columns)
    lies within `_UP_MAX_DEG` of `normal`."""
    h, w = Pg.shape[:2]
    up = np.zeros((h, w), dtype=bool)
    if h < 5 or w < 5:
        return up
    du = Pg[2:-2, 4:] - Pg[2:-2, :-4]
    dv = Pg[4:, 2:-2] - Pg[:-4, 2:-2]
    n = np.cross(du, dv)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(n @ normal) / np.linalg.norm(n, axis=-1)
        up[2:-2, 2:-2] = cos > np.cos(np.radians(_UP_MAX_DEG))
    return up


def _stands_on_face(face: np.ndarray, upper: np.ndarray, low: np.ndarray, min_cells: int) -> bool:
    """Whether the plane points (N, 2) of what rises above a top face (`upper`) stand on the face (`face`)
    of a solid whose sides are its cells below half the face's height (`low`): the face shows
    `_FACE_FREE_AREA_M2` beside the upper points, `_UPPER_OVER_SHARE` of those lie `_INSIDE_FACE_M` inside
    the face's outline, and `min_cells` or more low cells, `_WALL_EDGE_SHARE` of them, lie within
    `_WALL_BAND_M` of it. All on a raster of `_AREA_PITCH_M`; the outline is the convex hull of the face's
    points, since the face round the upper object's foot is hidden by it."""
    if len(low) < min_cells:
        return False
    band = int(np.ceil(_WALL_BAND_M / _AREA_PITCH_M))
    origin = np.min([face.min(axis=0), upper.min(axis=0), low.min(axis=0)], axis=0)
    fb, ub, lb = (
        np.floor((p - origin) / _AREA_PITCH_M).astype(np.int64) + band + 1 for p in (face, upper, low)
    )
    shape = np.max([fb.max(axis=0), ub.max(axis=0), lb.max(axis=0)], axis=0) + band + 2
    free = np.zeros((int(shape[0]), int(shape[1])), dtype=np.uint8)
    free[fb[:, 0], fb[:, 1]] = 1
    free[ub[:, 0], ub[:, 1]] = 0
    if np.count_nonzero(free) * _AREA_PITCH_M**2 < _FACE_FREE_AREA_M2:
        return False
    hull = np.zeros_like(free)
    cv2.fillConvexPoly(hull, cv2.convexHull(fb[:, ::-1].astype(np.int32)), 1)
    inside = int(np.ceil(_INSIDE_FACE_M / _AREA_PITCH_M))
    inner = cv2.erode(hull, np.ones((2 * inside + 1, 2 * inside + 1), np.uint8))
    if np.mean(inner[ub[:, 0], ub[:, 1]]) < _UPPER_OVER_SHARE:
        return False
    kernel = np.ones((2 * band + 1, 2 * band + 1), np.uint8)
    edge = (cv2.dilate(hull, kernel) > 0) & (cv2.erode(hull, kernel) == 0)  # the outline's band
    return bool(np.mean(edge[lb[:, 0], lb[:, 1]]) >= _WALL_EDGE_SHARE)


def _face_height(h: np.ndarray, up: np.ndarray, sigma: float) -> list[float]:
    """Candidate heights [m] of top faces among a segment's cells (heights `h`, `up`-facing mask), lowest
    first: the local maxima of the histogram of the up-facing cells' heights at `_FACE_MIN_H_M` or more, in
    bins of max(1 cm, 2 sigma) (at least 10 cells), each the median height of its bin and the two beside."""
    hu = h[up & (h >= _FACE_MIN_H_M)]
    if len(hu) < 10:
        return []
    width = max(0.01, 2.0 * sigma)
    bins = np.floor(hu / width).astype(np.int64)
    values, counts = np.unique(bins, return_counts=True)
    out = []
    for v, c in zip(values, counts, strict=True):
        near = np.abs(bins - v) <= 1
        if c >= 10 and c >= counts[np.abs(values - v) <= 1].max():  # a local maximum of the histogram
            out.append(float(np.median(hu[near])))
    return out


def _split_stacked(
    labels: np.ndarray,
    Pg: np.ndarray,
    plane: SupportPlane,
    plane_coords: Callable[[np.ndarray], np.ndarray],
    config: GroundingConfig,
    min_cells: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Grid labels with each object that stands on another's top face split off as its own segment, and
    the (K',) height [m] above `plane` of what each segment stands on (0: the plane; the face for those).

    In a segment, a top face is a level of up-facing cells (`_up_facing`, `_face_height`); the cells more
    than max(1 cm, 3 sigma(z)) above it are an object standing on it when they rise `_UPPER_MIN_RISE_M`
    above it and stand on the face (`_stands_on_face`: mostly over it, with face to spare beside them and
    walls under its edge: the lower object is a solid, not a part held up by a stem). Each 4-connected piece
    of those cells of `min_cells` or more is a new segment; the lowest face that passes is used. Without
    colour between them (an orange drill on a red box, one carton on another) only this tells them apart.
    """
    K = int(labels.max()) + 1
    base = [0.0] * K
    if K == 0:
        return labels, np.zeros(0)
    up = _up_facing(Pg, plane.normal_cam)
    with np.errstate(invalid="ignore"):
        height = Pg @ plane.normal_cam + plane.offset_m
    out = labels.copy()
    for k in range(K):
        own = (labels == k) & np.isfinite(height)
        if np.count_nonzero(own) < 2 * min_cells:
            continue
        h = height[own]
        sigma = float(np.median(config.sigma_m(Pg[own][:, 2])))
        xy = plane_coords(Pg[own])[:, :2]
        for face_h in _face_height(h, up[own], sigma):
            margin = max(0.01, 3.0 * sigma)
            upper = h > face_h + margin
            if np.count_nonzero(upper) < min_cells or h[upper].max() < face_h + _UPPER_MIN_RISE_M:
                continue
            face = up[own] & (np.abs(h - face_h) <= margin)
            if not _stands_on_face(xy[face], xy[upper], xy[h < 0.5 * face_h], min_cells):
                continue
            cells = np.zeros(labels.shape, dtype=bool)
            cells[own] = upper
            n, comp = cv2.connectedComponents(cells.view(np.uint8), connectivity=4)
            split = False
            for c in range(1, n):
                piece = comp == c
                if np.count_nonzero(piece) >= min_cells:
                    out[piece] = len(base)
                    base.append(face_h)
                    split = True
            if split:
                break
    return out, np.asarray(base)
