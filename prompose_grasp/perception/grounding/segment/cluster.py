"""Clustering of the pixel grid: neighbours join when close in 3D for their depth and close in colour
(`_grid_labels`); segments too small to keep merge into their geometric neighbour, or, as fragments of a thin
part (a mug's handle), into the nearest large segment, or chain with each other (`_merge_small`)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from prompose_grasp.perception.grounding.segment.cells import _colour_distance
from prompose_grasp.perception.grounding.types import GroundingConfig

#: The steepest surface (angle between surface normal and viewing ray) whose grid neighbours still join:
#: neighbours one grid step apart are s z / f apart across the ray and up to s z / (f cos 75 deg)
#: = 3.9 s z / f along it, so the side of a can seen at a grazing angle stays one piece.
_GRAZING_FACTOR = 1.0 / np.cos(np.radians(75.0))

#: A small segment with no geometric neighbour (a piece of a thin part: a mug's handle, whose depth the sensor
#: loses in a band along each of its edges, arrives as fragments with no depth between them and the body)
#: joins the nearest large segment within this distance [m] of at least `_FRAGMENT_NEAR_SHARE` of its cells:
#: a handle's root is ~1-2 cm off its body (the lost band), its far side 3-5 cm.
_FRAGMENT_JOIN_M = 0.025
_FRAGMENT_NEAR_SHARE = 0.25

#: ... when it stands at least this high above the support [m]: specks of table noise just past the height
#: cut (8-10 mm) stay dropped.
_FRAGMENT_MIN_HEIGHT_M = 0.02

#: Small pieces that join nothing (`_attach_fragments`) chain to each other within this distance [m]; a chain
#: of at least half the minimum segment size is a segment (`_chain_pieces`). A laptop screen seen edge-on has
#: depth only in pieces of 1-7 grid cells, 1-2 cm apart along its 20 cm of height (dev 28 scene 122): each
#: alone is too small and too far from the base to join it, so the candidate was the base alone, a "flat"
#: object.
_PIECE_CHAIN_M = 0.025


def _grid_labels(
    P: np.ndarray,
    lab: np.ndarray,
    fg: np.ndarray,
    f_px: float,
    s: int,
    config: GroundingConfig,
    crease: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of the grid graph, and the geometric-only neighbour pairs (for merging).

    Neighbours join when both are above the plane, close in 3D and in colour, and neither lies in a concave
    crease (`crease`, optional); crease points are left as single cells and merge into a neighbour later.
    """
    h, w = fg.shape
    ids = np.arange(h * w).reshape(h, w)
    z = P[..., 2]
    rows_a, rows_b, geo_a, geo_b = [], [], [], []
    # the wide colour test compares the cells one step before a and one step after b (a 4-cell baseline):
    # an edge blurred over two or three cells (anti-aliasing, the sensor's optics, the grid's area
    # averaging) has no single neighbour step above `colour_edge` but is one across the baseline
    labp = np.pad(lab, ((1, 1), (1, 1), (0, 0)), mode="edge")
    for sl_a, sl_b, before, after in (
        ((slice(None), slice(0, w - 1)), (slice(None), slice(1, w)),
         labp[1:-1, 0 : w - 1], labp[1:-1, 3 : w + 2]),
        ((slice(0, h - 1), slice(None)), (slice(1, h), slice(None)),
         labp[0 : h - 1, 1:-1], labp[3 : h + 2, 1:-1]),
    ):  # fmt: skip
        both = fg[sl_a] & fg[sl_b]
        za = np.where(both, z[sl_a], 0.0)
        # noise of a difference of two readings is sqrt(2) sigma; plus a grazing surface's spacing
        gap = (
            np.maximum(
                config.neighbour_gap_min_m, config.neighbour_gap_sigmas * np.sqrt(2.0) * config.sigma_m(za)
            )
            + _GRAZING_FACTOR * s * za / f_px
        )
        d3 = np.linalg.norm(P[sl_a] - P[sl_b], axis=-1)
        with np.errstate(invalid="ignore"):
            geo = both & (d3 < gap)
        col = geo & (_colour_distance(lab[sl_a], lab[sl_b]) < config.colour_edge)
        wide = _colour_distance(before, after)
        if config.wide_colour_edge < np.inf:
            col &= wide < config.wide_colour_edge
        if crease is not None:
            col &= ~(crease[sl_a] | crease[sl_b])
        rows_a.append(ids[sl_a][col])
        rows_b.append(ids[sl_b][col])
        geo_a.append(ids[sl_a][geo & ~col])
        geo_b.append(ids[sl_b][geo & ~col])
    a = np.concatenate(rows_a)
    b = np.concatenate(rows_b)
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(h * w, h * w))
    _, labels = connected_components(graph, directed=False)
    labels = labels.reshape(h, w)
    labels[~fg] = -1
    return labels, np.stack([np.concatenate(geo_a), np.concatenate(geo_b)])


def _merge_small(
    labels: np.ndarray,
    geo_pairs: np.ndarray,
    min_cells: int,
    points: np.ndarray | None = None,
    heights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Relabel 0..K-1 after merging segments below `min_cells` grid cells into their geometric neighbour.

    With the cells' `points` (H, W, 3) and `heights` above the support (H, W), a small segment without a
    geometric neighbour joins the nearest large segment in 3D instead of being dropped, when it stands at
    least `_FRAGMENT_MIN_HEIGHT_M` high and lies within `_FRAGMENT_JOIN_M` of it (`_attach_fragments`).

    Returns the labels and an (H, W) bool map of the cells of such attached fragments.
    """
    flat = labels.ravel()
    fg = flat >= 0
    attached = np.zeros(labels.shape, dtype=bool)
    if not np.any(fg):
        return labels, attached
    uniq, inverse, counts = np.unique(flat[fg], return_inverse=True, return_counts=True)
    compact = np.full(flat.shape, -1, dtype=np.int64)
    compact[fg] = inverse
    small = counts < min_cells
    target = np.arange(len(uniq))
    if np.any(small) and geo_pairs.shape[1]:
        la, lb = compact[geo_pairs[0]], compact[geo_pairs[1]]
        pairs = np.concatenate([np.stack([la, lb], 1), np.stack([lb, la], 1)])
        pairs = pairs[small[pairs[:, 0]] & ~small[pairs[:, 1]]]
        if len(pairs):
            pu, pc = np.unique(pairs, axis=0, return_counts=True)
            order = np.lexsort((-pc, pu[:, 0]))  # per small segment, the neighbour with most shared edges
            pu = pu[order]
            first = np.r_[True, pu[1:, 0] != pu[:-1, 0]]
            target[pu[first, 0]] = pu[first, 1]
    chained = np.zeros(len(uniq), dtype=bool)
    if points is not None and heights is not None:
        alone = small & (target == np.arange(len(uniq)))
        _attach_fragments(target, compact, alone, points.reshape(-1, 3), heights.ravel())
        joined = alone & (target != np.arange(len(uniq)))
        attached = (fg & joined[np.maximum(compact, 0)]).reshape(labels.shape)
        chained = _chain_pieces(target, compact, alone & ~joined, counts, min_cells, points, heights)
    keep = ~small | (target != np.arange(len(uniq))) | chained
    target = np.where(keep, target, -1)
    out = np.where(fg, target[np.maximum(compact, 0)], -1)
    # relabel to 0..K-1 in order of first appearance (raster order: deterministic)
    vals = out[out >= 0]
    _, first_idx = np.unique(vals, return_index=True)
    old = vals[np.sort(first_idx)]
    remap = np.full(len(uniq), -1, dtype=np.int64)
    remap[old] = np.arange(len(old))
    out = np.where(out >= 0, remap[np.maximum(out, 0)], -1)
    return out.reshape(labels.shape), attached


def _attach_fragments(
    target: np.ndarray, compact: np.ndarray, alone: np.ndarray, P: np.ndarray, heights: np.ndarray
) -> None:
    """Point each segment of `alone` (small, no geometric neighbour) in `target` to a large segment, when at
    least `_FRAGMENT_NEAR_SHARE` of its cells stand `_FRAGMENT_MIN_HEIGHT_M` or more above the support
    within `_FRAGMENT_JOIN_M` of a large segment in 3D: to the one most of those cells are nearest to (in
    place; `compact`: each cell's segment, -1 for none)."""
    large = ~alone & (target == np.arange(len(target)))
    cells = np.nonzero(compact >= 0)[0]
    seg = compact[cells]
    frag_cells = cells[alone[seg]]
    big_cells = cells[large[seg]]
    if not len(frag_cells) or not len(big_cells):
        return
    frag_cells = frag_cells[heights[frag_cells] >= _FRAGMENT_MIN_HEIGHT_M]
    if not len(frag_cells):
        return
    d, j = cKDTree(P[big_cells]).query(P[frag_cells], k=1, distance_upper_bound=_FRAGMENT_JOIN_M)
    near = np.isfinite(d)
    frag_seg = compact[frag_cells]
    for k in np.unique(frag_seg):
        mine = frag_seg == k
        # enough of the fragment within reach (a handle's root: the median cell of a handle reaching 3-4 cm
        # off its body was 26-27 mm away, dev 29), joined to the segment most of those cells are near
        if np.count_nonzero(near & mine) >= _FRAGMENT_NEAR_SHARE * np.count_nonzero(compact == k):
            owners = compact[big_cells[j[near & mine]]]
            target[k] = int(np.bincount(owners).argmax())


def _chain_pieces(
    target: np.ndarray,
    compact: np.ndarray,
    pieces: np.ndarray,
    counts: np.ndarray,
    min_cells: int,
    points: np.ndarray,
    heights: np.ndarray,
) -> np.ndarray:
    """Chain the small segments of `pieces` (bool per segment) whose cells standing `_FRAGMENT_MIN_HEIGHT_M`
    or more above the support come within `_PIECE_CHAIN_M` of each other; a chain of half `min_cells` or
    more cells becomes one segment (in place: `target` of its pieces points to its first piece), whose
    painted mask must still reach the minimum size. Returns the bool per segment of those first pieces
    (kept, though small)."""
    roots = np.zeros(len(target), dtype=bool)
    cells = np.nonzero((compact >= 0) & (heights.ravel() >= _FRAGMENT_MIN_HEIGHT_M))[0]
    cells = cells[pieces[compact[cells]]]
    # depth drops out over much of a small object's surface (a band along each of its edges), so its cells
    # with depth under-count it: a chain of half the minimum's cells is kept, and its painted mask (the
    # pixels of its colour without depth filled in) is judged by the minimum size
    least = (min_cells + 1) // 2
    if len(cells) < 2 or counts[pieces].sum() < least:
        return roots
    links = cKDTree(points.reshape(-1, 3)[cells]).query_pairs(_PIECE_CHAIN_M, output_type="ndarray")
    if not len(links):
        return roots
    seg = compact[cells]
    n = len(target)
    graph = coo_matrix(
        (np.ones(len(links), dtype=np.int8), (seg[links[:, 0]], seg[links[:, 1]])), shape=(n, n)
    )
    _, chain = connected_components(graph, directed=False)
    members = np.unique(seg)
    size = np.bincount(chain[members], weights=counts[members], minlength=n)
    for c in np.unique(chain[members]):
        mine = members[chain[members] == c]
        if len(mine) > 1 and size[c] >= least:
            target[mine] = mine[0]
            roots[mine[0]] = True
    return roots
