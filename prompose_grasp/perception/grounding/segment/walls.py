"""Background segments: walls, shelves and counters' backs (`_wall_segments`), split again at concave creases
first in case objects touch them (`_split_and_drop_walls`)."""

from __future__ import annotations

import cv2
import numpy as np

from prompose_grasp.perception.grounding.plane import PlaneFrame
from prompose_grasp.perception.grounding.segment.cells import concave_creases
from prompose_grasp.perception.grounding.segment.cluster import _grid_labels, _merge_small
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

#: A segment whose highest point comes within this of `max_height_m` [m] is cut off by it: a wall or a
#: shelf, not an object (2 cm: the height cut's own noise at 1.5 m is under 1 cm).
_WALL_TOP_M = 0.02

#: A segment whose footprint (the longer side of the minimum-area rectangle of its points on the plane) is
#: longer than this [m] is not a tabletop object: the largest the synthetic sets hold are 0.6 m cartons
#: and 0.35 m laptops; a wall's foot or a counter's back runs across the whole view.
_WALL_SPAN_M = 0.8

#: Segments with a footprint longer than this [m], and walls, are split again at concave creases
#: (`concave_creases`) before walls are dropped. 0.45 m is above every object of the synthetic sets but
#: their largest cartons (convex: no creases to cut), so their masks stay as they were (cutting creases
#: everywhere cost 1.4 points of mean mask IoU there, at mug handles and laptop hinges), and below a
#: robot's base with a box leaning on it.
_RESPLIT_SPAN_M = 0.45


def _wall_segments(
    labels: np.ndarray, Pg: np.ndarray, plane: SupportPlane, config: GroundingConfig, span_m: float = 0.0
) -> np.ndarray:
    """(K,) bool: segments that rise to the height cut or sprawl wider than a tabletop object (walls).

    A segment reaching within `_WALL_TOP_M` of `max_height_m` continues above the cut (nothing graspable
    is that tall), and one whose points spread over more than `_WALL_SPAN_M` along the plane is the base of
    a wall or a counter's back; either is background, and removing it before `_join_surfaces` keeps it from
    joining the objects standing against it.
    """
    K = int(labels.max()) + 1
    if K == 0:
        return np.zeros(0, dtype=bool)
    flat = labels.ravel()
    sel = flat >= 0
    lab = flat[sel]
    pts = Pg.reshape(-1, 3)[sel]
    ok = np.isfinite(pts[:, 2])
    lab, pts = lab[ok], pts[ok]
    h = pts @ plane.normal_cam + plane.offset_m
    top = np.full(K, -np.inf)
    np.maximum.at(top, lab, h)
    # footprint length: the longer side of the minimum-area rectangle of the points on the plane
    xy = PlaneFrame(plane).coords(pts)[:, :2].astype(np.float32)
    order = np.argsort(lab, kind="stable")
    starts = np.searchsorted(lab[order], np.arange(K + 1))
    span = np.zeros(K)
    for k in range(K):
        idx = order[starts[k] : starts[k + 1]]
        if len(idx) >= 3:
            span[k] = max(cv2.minAreaRect(xy[idx[:: max(1, len(idx) // 2000)]])[1])
    return (top > config.max_height_m - _WALL_TOP_M) | (span > (span_m or _WALL_SPAN_M))


def _drop_walls(
    labels: np.ndarray, Pg: np.ndarray, plane: SupportPlane, config: GroundingConfig
) -> np.ndarray:
    """Labels 0..K'-1 without the `_wall_segments`."""
    wall = _wall_segments(labels, Pg, plane, config)
    if not np.any(wall):
        return labels
    out = np.where(labels >= 0, np.where(wall[np.maximum(labels, 0)], -1, labels), -1)
    _, new = np.unique(out[out >= 0], return_inverse=True)
    out[out >= 0] = new
    return out


def _split_and_drop_walls(
    labels: np.ndarray,
    Pg: np.ndarray,
    lab_g: np.ndarray,
    f_px: float,
    s: int,
    plane: SupportPlane,
    config: GroundingConfig,
    min_cells: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Grid labels without the walls, and the (h, w) bool background cells no mask may grow into (the
    walls' cells and the crease cells of the segments split again).

    A wall or a segment with a footprint longer than `_RESPLIT_SPAN_M` may be objects joined to each other,
    to a wall or to a robot's base through touching surfaces of similar colour: it is split again, this time
    also at concave creases (`concave_creases`), and the pieces that are not walls themselves are kept.
    """
    wall = _wall_segments(labels, Pg, plane, config, span_m=_RESPLIT_SPAN_M)
    resplit = np.zeros(labels.shape, dtype=bool)
    if np.any(wall) and config.crease_sigmas < np.inf:
        crease = concave_creases(Pg[..., 2], config)
        inside = wall[np.maximum(labels, 0)] & (labels >= 0)
        resplit = inside
        # crease cells themselves join nothing: left out (the masks' one-step growth paints the
        # objects' side of the band back), not merged into whichever piece they touch most
        split, geo2 = _grid_labels(Pg, lab_g, inside & ~crease, f_px, s, config, crease)
        split, _ = _merge_small(split, geo2, min_cells)
        labels = np.where(inside, np.where(split >= 0, split + labels.max() + 1, -1), labels)
        _, relabel = np.unique(labels, return_inverse=True)  # -1 stays first
        labels = relabel.reshape(labels.shape) - (1 if np.any(labels < 0) else 0)
    kept = _drop_walls(labels, Pg, plane, config)
    background = ((labels >= 0) | resplit) & (kept < 0)  # walls, creases: no mask grows into them
    return kept, background
