"""Where an object's silhouette is not its own end: a nearer surface beside it, and the sides that cuts off.

An object seen between two nearer boxes, or half behind a bottle, shows a silhouette whose edge there is the
occluder's. Its seen extent along that direction is not its size. The pose fit (`perception.fit`) then lets
the prior's aspect fill the cut side. (The grounder does not use these: not judging a cut footprint's size
or shape was tried and cost more than it found, docs/grounding.md, "Cups and cameras told from mugs".)
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

__all__ = ["cut_ends", "nearer_beside"]


def nearer_beside(
    depth_m: np.ndarray,
    mask: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    depth_at: np.ndarray,
    radius_px: int,
    margin_m: float,
) -> np.ndarray:
    """(N,) bool: pixels (rows, cols) of an object with a pixel off its `mask` within `radius_px` (a square
    window) whose depth reading is nearer than `depth_at` by more than `margin_m`: there the silhouette is
    an occluder's edge.

    Args:
        depth_m: (H, W) depth [m]; 0 or NaN where there is no reading (never an occluder).
        mask: (H, W) bool pixels of the object.
        rows, cols: (N,) int pixel indices inside the image.
        depth_at: (N,) the object's depth at those pixels [m].
        radius_px: half the window's side [px].
        margin_m: how much nearer an occluder must read (above the depth noise) [m].
    """
    out = np.zeros(len(rows), dtype=bool)
    if len(rows) == 0:
        return out
    r = int(radius_px)
    height, width = depth_m.shape
    x0, x1 = max(0, int(cols.min()) - r), min(width, int(cols.max()) + r + 1)
    y0, y1 = max(0, int(rows.min()) - r), min(height, int(rows.max()) + r + 1)
    d = depth_m[y0:y1, x0:x1]
    with np.errstate(invalid="ignore"):
        other = ~mask[y0:y1, x0:x1] & (d > 0.0)  # NaN (no reading) compares False
    nearest = minimum_filter(np.where(other, d, np.inf), size=2 * r + 1, mode="constant", cval=np.inf)
    return nearest[rows - y0, cols - x0] < depth_at - margin_m


def cut_ends(
    local: np.ndarray, lo: np.ndarray, hi: np.ndarray, cut_edge: np.ndarray, share: float
) -> np.ndarray:
    """(D, 2) bool: which ends (low, high) of each of D axes a cut edge cuts off.

    An end is cut when at least `share` of the points at it (at or beyond the low `lo` / high `hi` value
    along the axis: the outer few per cent) lie on a cut edge: where the cut crosses the object's end, the
    farthest points along the axis are the cut's; at a free end they are the object's own silhouette.

    Args:
        local: (N, D) points in the axes' frame.
        lo, hi: (D,) the ends' bounds (e.g. 2nd and 98th percentiles of `local`).
        cut_edge: (N,) bool, the points on a cut edge (image border, `nearer_beside`).
        share: the share of an end's points that makes it cut.
    """
    D = local.shape[1]
    cut = np.zeros((D, 2), dtype=bool)
    if not np.any(cut_edge):
        return cut
    for i in range(D):
        for j, end in enumerate((local[:, i] <= lo[i], local[:, i] >= hi[i])):
            cut[i, j] = np.count_nonzero(end & cut_edge) >= share * np.count_nonzero(end)
    return cut
