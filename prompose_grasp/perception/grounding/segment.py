"""Object candidates above the support plane: graph clustering on a pixel grid, then full-resolution masks.

Clustering works on every `segment_stride_px`-th pixel. Two 4-neighbours on that grid join when both are
above the plane, their 3D distance is small for their depth (the sensor's noise plus the spacing a steep
surface shows) and their colours are close (a colour edge splits touching objects of different colour).
Tiny segments (specular highlights, speckle) merge into the segment they touch geometrically, or vanish.
Each segment is then painted at full resolution: the pixels of its grid cells that are above the plane,
grown by the grid spacing into above-plane pixels, plus pixels without depth (occlusion shadows, holes)
around it whose colour matches it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from prompose_grasp.perception.grounding.plane import PlaneFrame
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

__all__ = ["Segment", "concave_creases", "lab_image", "segment_objects"]

#: The steepest surface (angle between surface normal and viewing ray) whose grid neighbours still join:
#: neighbours one grid step apart are s z / f apart across the ray and up to s z / (f cos 75 deg)
#: = 3.9 s z / f along it, so the side of a can seen at a grazing angle stays one piece.
_GRAZING_FACTOR = 1.0 / np.cos(np.radians(75.0))

#: Pixels without depth join a segment when their Lab colour is within this many `colour_edge` of the
#: segment's median (shading over an object spans more than one neighbour-to-neighbour edge).
_FILL_COLOUR_FACTOR = 2.0

#: Adjacent segments of one colour whose footprints come closer than this [m] are one object seen as two
#: surfaces (the outside of a bowl and its inside, a mug and the inside of its opening): the depth jump at
#: the rim cuts the grid graph, but both surfaces stand on the same spot of the plane. 3 cm: a mug's front
#: wall and the back of its inside meet only at the rim's ends, measured 2.2 cm apart on the footprint when
#: the rim's middle is hidden; 2 cm left such mugs in two halves (IoU ~0.45 each).
_FOOTPRINT_JOIN_M = 0.03

#: Segments are "adjacent" when their grid cells come within this many cells: the rim's depth jump leaves a
#: band without depth between the two surfaces (the sensor drops a 2 px band on each side of a jump, and a
#: thin rim adds its own), up to ~8 px at a 2 px grid.
_ADJACENT_CELLS = 4

#: An inner floor pixel (`_inner_floor`) may read this many sigma(z) below the plane (noise), not more: a
#: pixel far below the plane is something else seen through a gap.
_INNER_FLOOR_SIGMAS = 3.0

#: ... and lie within this distance [m] of the object's footprint (`_inner_floor`). The footprint is the hull
#: of the points above the height cut; a floor seen right up to a thin rim's edge at a slant lies beyond the
#: rim's own points by its parallax (`test_inner_floor_of_a_tray_joins_its_walls`: a 4 cm rim needs ~2 cm).
#: Dev split seed 22, grounded masks' precision / recall: laptops 0.949 / 0.938 (no footprint test) ->
#: 0.986 / 0.935 (0 cm) -> 0.981 / 0.938 (2 cm), mugs 0.951 / 0.923 -> 0.962 / 0.918 -> 0.959 / 0.923.
_FLOOR_FOOTPRINT_MARGIN_M = 0.02

#: `_join_hinged`: a slab is flat under this height [m] (a laptop base is 1.5-3 cm), a panel thinner than
#: this footprint width [m] (a screen seen from behind shows 4-8 cm of footprint at its tilt), and the two
#: footprints come within this [m]: the screen hides the hinge and a strip of the base up to its height
#: times cot(elevation), 12 cm for a 21 cm screen seen from 60 deg (measured 5.3 and 9.5 cm on the
#: synthetic test split).
_HINGE_SLAB_MAX_H_M = 0.04
_HINGE_PANEL_MAX_W_M = 0.09
_HINGE_GAP_M = 0.12
#: ... or, for a slab and a panel of one colour (`_shade_distance` under `colour_edge`), within the panel's
#: height: from 45 deg of elevation the screen hides up to its height of the base (dev split 29: two laptops
#: seen from behind and low showed a 5-8 cm strip of their base 14-15 cm in front of a 21-23 cm screen).
#: A panel leaning back (a screen opened past 110 deg: 11-15 cm of footprint on dev split 29) is wider than
#: `_HINGE_PANEL_MAX_W_M`, yet still flat: its points lie within this [m] of one plane (the 5-95 percentile
#: spread along their least principal axis; a 5-9 mm screen plus the sensor's noise) ...
_HINGE_PANEL_MAX_T_M = 0.025
#: ... and that plane is steep: its normal's vertical component under this (a lean under 45 deg; a box's
#: top face, as flat, is horizontal: 1).
_HINGE_PANEL_MAX_NORMAL_UP = 0.7

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
#: of at least the minimum segment size is a segment. A laptop screen seen edge-on has depth only in pieces of
#: 1-7 grid cells, 1-2 cm apart along its 20 cm of height (dev 28 scene 122): each alone is too small and
#: too far from the base to join it, so the candidate was the base alone, a "flat" object.
_PIECE_CHAIN_M = 0.025

#: A thin part under the height cut (a laptop's 12-22 mm base at 1 m, where the cut is 2.5 sigma = 12 mm)
#: still counts as above the support where it stands this many sigma(z) and at least `_THIN_MIN_M` up, is
#: not of the support's colour, and joins a cell above the cut through such cells (`_thin_parts`).
_THIN_SIGMAS = 1.5
_THIN_MIN_M = 0.005
#: An object lower than the cut everywhere (`_flat_objects`): at least this many grid cells, their mean
#: height this many standard errors above the plane.
_FLAT_MIN_CELLS = 20
_FLAT_SIGMAS = 6.0
_FLAT_MAX_FG_SHARE = 0.3

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
    """

    mask: np.ndarray
    points_cam: np.ndarray
    box_xyxy: np.ndarray


def lab_image(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 CIE Lab (L in [0, 100], a and b in about [-128, 127]) of (H, W, 3) uint8 RGB."""
    return cv2.cvtColor(rgb.astype(np.float32) * (1.0 / 255.0), cv2.COLOR_RGB2Lab)


def _colour_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Lab distance with lightness at half weight: shading changes L much more than it changes a and b."""
    d = a - b
    return np.sqrt(0.25 * d[..., 0] ** 2 + d[..., 1] ** 2 + d[..., 2] ** 2)


def _height_cut(z: np.ndarray, config: GroundingConfig) -> np.ndarray:
    """(...,) the noise-aware height cut [m] at depths `z`: max(`min_height_m`, `height_sigmas` sigma(z))."""
    return np.maximum(config.min_height_m, config.height_sigmas * config.sigma_m(z))


def _above(points: np.ndarray, plane: SupportPlane | None, config: GroundingConfig) -> np.ndarray:
    """(...,) bool: valid points above the noise-aware height cut (all valid points without a plane)."""
    z = points[..., 2]
    valid = np.isfinite(z)
    if plane is None:
        return valid
    with np.errstate(invalid="ignore"):
        h = points @ plane.normal_cam + plane.offset_m
        return valid & (h > _height_cut(z, config)) & (h < config.max_height_m)


def _support_colour(
    Pg: np.ndarray, lab_g: np.ndarray, plane: SupportPlane, config: GroundingConfig
) -> np.ndarray | None:
    """(3,) Lab median colour of the grid cells within the height cut of the plane (the support's own
    colour), or None when fewer than 10 cells lie there."""
    z = Pg[..., 2]
    with np.errstate(invalid="ignore"):
        support = np.isfinite(z) & (np.abs(Pg @ plane.normal_cam + plane.offset_m) < _height_cut(z, config))
    if np.count_nonzero(support) < 10:
        return None
    table = lab_g[support]
    return np.median(table[:: max(1, len(table) // 4000)], axis=0)  # 4000 cells pin a median


def _thin_parts(
    fg: np.ndarray,
    Pg: np.ndarray,
    lab_g: np.ndarray,
    plane: SupportPlane,
    config: GroundingConfig,
    table_lab: np.ndarray | None,
) -> np.ndarray:
    """`fg` (the grid cells above the height cut) plus the cells of thin parts under it: cells standing
    `_THIN_SIGMAS` sigma(z) (and `_THIN_MIN_M`) up, whose colour differs from the support's (`table_lab`,
    `_support_colour`; None: no thin parts) by `colour_edge`, connected to a cell of `fg` through such cells.
    Table noise passes the lower cut in ~7 % of the cells, as specks of the table's colour; a laptop's base
    at 1 m passes it whole, where the full cut leaves scattered cells too small to keep."""
    z = Pg[..., 2]
    valid = np.isfinite(z)
    with np.errstate(invalid="ignore"):
        h = Pg @ plane.normal_cam + plane.offset_m
        low = valid & ~fg & (h > np.maximum(_THIN_MIN_M, _THIN_SIGMAS * config.sigma_m(z)))
        low &= h < config.max_height_m
    if not np.any(low) or table_lab is None:
        return fg
    low[low] = _colour_distance(lab_g[low], table_lab) >= config.colour_edge  # only the candidates' colours
    _, comp = cv2.connectedComponents((fg | low).view(np.uint8), connectivity=4)
    seeded = np.zeros(int(comp.max()) + 1, dtype=bool)
    seeded[comp[fg]] = True
    return fg | (low & seeded[comp])


def _flat_objects(
    fg: np.ndarray,
    Pg: np.ndarray,
    lab_g: np.ndarray,
    plane: SupportPlane,
    config: GroundingConfig,
    table_lab: np.ndarray | None,
) -> np.ndarray:
    """(h, w) int grid labels 0..F-1 (-1 elsewhere) of objects lower than the height cut almost everywhere (a
    knife or a toothbrush lying flat: 12-15 mm, where the cut is 2.5 sigma(z) = 16-20 mm at 1.2-1.35 m).

    Such an object shows a few cells above the cut at most, and one by one its cells are within the noise
    (sigma(z) 6-8 mm there). Together they are not: a piece of cells of a colour off the support's
    (`table_lab` by `colour_edge`; None: none found; 8-connected across gaps of a cell, a knife is 1-2 cells
    wide) within the height band (from minus the cut to `max_height_m`), outside any solid piece of cells
    above the cut (at least `_FLAT_MIN_CELLS` of them: a standing object's; the few cells a flat object's
    noise lifts over the cut are scattered), holding at least `_FLAT_MIN_CELLS` cells, at most
    `_FLAT_MAX_FG_SHARE` of them beside such a solid piece (else it is the low part of that object: a rim, a
    base), whose mean height is at least `_FLAT_SIGMAS` standard errors (sigma(z) / sqrt(n)) and
    `_THIN_MIN_M` above the plane. A patch of the table's own texture, or a sheet lying on it, has a mean
    height near zero. Each piece is one object: the grid's clustering splits its cells, whose depths differ
    by the noise, into pieces too small to keep.
    """
    z = Pg[..., 2]
    valid = np.isfinite(z)
    with np.errstate(invalid="ignore"):
        h = Pg @ plane.normal_cam + plane.offset_m
        cut = _height_cut(z, config)
        band = valid & (h > -cut) & (h < config.max_height_m)
    out = np.full(fg.shape, -1, dtype=np.int64)
    if table_lab is None:
        return out
    # cells above the cut in a solid piece are a standing object's; the few a flat object's noise lifts over
    # the cut are scattered
    _, fg_comp = cv2.connectedComponents(fg.view(np.uint8), connectivity=8)
    solid = fg & (np.bincount(fg_comp[fg], minlength=int(fg_comp.max()) + 1)[fg_comp] >= _FLAT_MIN_CELLS)
    coloured = band & ~solid & (_colour_distance(lab_g, table_lab) >= config.colour_edge)
    # a cell or two of a thin object blend with the table at its edges: pieces a cell apart are one
    joined = cv2.morphologyEx(coloured.view(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, comp = cv2.connectedComponents(joined, connectivity=8)
    if n <= 1:
        return out
    c, cells = comp[coloured], np.bincount(comp[coloured], minlength=n).astype(np.float64)
    per_cell = np.maximum(cells, 1.0)
    mean_h = np.bincount(c, weights=h[coloured], minlength=n) / per_cell
    sigma = np.bincount(c, weights=config.sigma_m(z[coloured]), minlength=n) / per_cell
    # a piece lying mostly beside a solid piece above the cut is that object's low part (a rim, a base)
    near_fg = cv2.dilate(solid.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    fg_share = np.bincount(c, weights=near_fg[coloured].astype(np.float64), minlength=n) / per_cell
    ok = (cells >= _FLAT_MIN_CELLS) & (fg_share <= _FLAT_MAX_FG_SHARE)
    ok &= mean_h >= np.maximum(_THIN_MIN_M, _FLAT_SIGMAS * sigma / np.sqrt(per_cell))
    ok[0] = False
    keep = ok[comp] & coloured
    _, out[keep] = np.unique(comp[keep], return_inverse=True)
    return out


def concave_creases(z: np.ndarray, config: GroundingConfig, k: int = 0) -> np.ndarray:
    """(h, w) bool: grid points in a concave crease of the depth surface (where two touching objects meet).

    Inverse depth is affine in the pixel coordinates over any plane, so its second difference over
    +-`k` grid cells, along rows, columns and both diagonals, is zero on flat surfaces and on convex ones
    negative. Where the surface folds away from the camera (a valley: a can lying against a box, a box
    against a robot's base) the point is farther than the mean of its two neighbours. The largest such
    depth excess (second difference x z^2, in metres) over the four directions is compared with
    `crease_sigmas` x sigma(z) of the sensor noise model.

    Args:
        z: (h, w) float64 depth of the grid [m], NaN where there is none (NaN neighbours never flag).
        config: `crease_sigmas`, `crease_cells` and the noise model.
        k: half-width in grid cells; 0: `config.crease_cells`.
    """
    k = k or config.crease_cells
    h, w = z.shape
    out = np.zeros((h, w), dtype=bool)
    if h <= 2 * k or w <= 2 * k:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        iz = 1.0 / z
        excess = np.zeros((h, w))
        c = iz[k : h - k, k : w - k]
        for dy, dx in ((0, k), (k, 0), (k, k), (k, -k)):
            a = iz[k - dy : h - k - dy, k - dx : w - k - dx]
            b = iz[k + dy : h - k + dy, k + dx : w - k + dx]
            q = 0.5 * (a + b) - c
            excess[k : h - k, k : w - k] = np.fmax(excess[k : h - k, k : w - k], np.nan_to_num(q))
        excess *= np.nan_to_num(z) ** 2
        out = excess > config.crease_sigmas * np.asarray(config.sigma_m(np.nan_to_num(z)))
    return out


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
    or more above the support come within `_PIECE_CHAIN_M` of each other; a chain of `min_cells` or more
    cells becomes one segment (in place: `target` of its pieces points to its first piece). Returns the
    bool per segment of those first pieces (kept, though small)."""
    roots = np.zeros(len(target), dtype=bool)
    cells = np.nonzero((compact >= 0) & (heights.ravel() >= _FRAGMENT_MIN_HEIGHT_M))[0]
    cells = cells[pieces[compact[cells]]]
    if len(cells) < 2 or counts[pieces].sum() < min_cells:
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
        if len(mine) > 1 and size[c] >= min_cells:
            target[mine] = mine[0]
            roots[mine[0]] = True
    return roots


def _adjacent_pairs(labels: np.ndarray) -> set[tuple[int, int]]:
    """Pairs (a, b), a < b, of labels whose cells come within `_ADJACENT_CELLS` of each other."""
    size = 2 * _ADJACENT_CELLS + 1
    kernel = np.ones((size, size), np.uint8)
    shifted = (labels + 1).astype(np.float32)  # -1 (none) -> 0
    hi = cv2.dilate(shifted, kernel) - 1.0
    big = np.where(labels >= 0, shifted, np.float32(1e9))
    lo = cv2.erode(big, kernel) - 1.0
    own = labels >= 0
    pairs: set[tuple[int, int]] = set()
    for other in (hi, lo):
        sel = own & (other >= 0) & (other < 1e8) & (other != labels)
        if np.any(sel):
            a = labels[sel]
            b = other[sel].astype(np.int64)
            for x, y in np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], 1), axis=0):
                pairs.add((int(x), int(y)))
    return pairs


def _join_surfaces(
    labels: np.ndarray, Pg: np.ndarray, lab_g: np.ndarray, plane_coords, config: GroundingConfig
) -> np.ndarray:
    """Merge adjacent segments of one colour that stand on the same footprint (see `_FOOTPRINT_JOIN_M`).

    Pairs are joined closest colours first, and only while the two groups' mean chromas (cell-weighted)
    stay within `colour_edge`: a chain of pairwise-similar segments (a red box, a red-brown drill handle,
    a red and white can) does not merge objects whose colours differ.
    """
    K = int(labels.max()) + 1
    if K < 2:
        return labels
    pairs = _adjacent_pairs(labels)
    if not pairs:
        return labels
    flat = labels.ravel()
    order = np.argsort(flat, kind="stable")
    starts = np.searchsorted(flat[order], np.arange(K + 1))
    P = Pg.reshape(-1, 3)
    L = lab_g.reshape(-1, 3)
    chroma, foot = [], []
    cells = np.diff(starts).astype(np.float64)
    for k in range(K):
        idx = order[starts[k] : starts[k + 1]]
        chroma.append(np.median(L[idx, 1:], axis=0))
        pts = P[idx]
        pts = pts[np.isfinite(pts[:, 2])]
        if len(pts) > 400:  # an even thinning keeps the outline; 400 points make the pair test cheap
            pts = pts[:: int(np.ceil(len(pts) / 400))]
        foot.append(plane_coords(pts)[:, :2] if plane_coords is not None else pts)
    parent = np.arange(K)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = int(parent[i])
        return i

    group_chroma = np.array(chroma, dtype=np.float64) * cells[:, None]  # sums, per root
    group_cells = cells.copy()
    trees: dict[int, cKDTree] = {}
    ranked = sorted(pairs, key=lambda ab: (_shade_distance(chroma[ab[0]], chroma[ab[1]]), ab))
    for a, b in ranked:
        if not len(foot[a]) or not len(foot[b]):
            continue
        if _shade_distance(chroma[a], chroma[b]) >= config.colour_edge:
            break  # sorted: no later pair is closer
        ra, rb = root(a), root(b)
        if ra == rb:
            continue
        mean_a, mean_b = group_chroma[ra] / group_cells[ra], group_chroma[rb] / group_cells[rb]
        if _shade_distance(mean_a, mean_b) >= config.colour_edge:
            continue
        if a not in trees:
            trees[a] = cKDTree(foot[a])
        d, _ = trees[a].query(foot[b], k=1, distance_upper_bound=_FOOTPRINT_JOIN_M)
        if np.min(d) < _FOOTPRINT_JOIN_M:
            lo, hi = min(ra, rb), max(ra, rb)
            parent[hi] = lo
            group_chroma[lo] += group_chroma[hi]
            group_cells[lo] += group_cells[hi]
    roots = np.array([root(k) for k in range(K)])
    _, new = np.unique(roots, return_inverse=True)
    return np.where(labels >= 0, new[np.maximum(labels, 0)], -1)


#: Two saturated chromas (Lab a, b) of one hue are one surface colour in two lights when their hue angles
#: differ by less than this [deg] ...
_SHADE_HUE_DEG = 6.0
#: ... both have at least this chroma (below it the hue angle is noise) ...
_SHADE_MIN_CHROMA = 20.0
#: ... and the larger is at most this times the smaller (a lit and a shaded face of one object).
_SHADE_MAX_RATIO = 1.7


def _shade_distance(c1: np.ndarray, c2: np.ndarray) -> float:
    """Distance of two (a, b) chromas for joining surfaces: the hue part only when they are one saturated
    hue in two lights (`_SHADE_HUE_DEG`, `_SHADE_MIN_CHROMA`, `_SHADE_MAX_RATIO`: a camera's lens facing the
    light and its body in shade, 90 vs 60 of chroma at one hue), else the plain Euclidean distance."""
    n1, n2 = float(np.hypot(*c1)), float(np.hypot(*c2))
    d = float(np.hypot(*(np.asarray(c1) - np.asarray(c2))))
    if min(n1, n2) < _SHADE_MIN_CHROMA or max(n1, n2) > _SHADE_MAX_RATIO * min(n1, n2):
        return d
    cos = float(np.dot(c1, c2)) / (n1 * n2)
    angle = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    if angle >= _SHADE_HUE_DEG:
        return d
    return min(n1, n2) * float(np.sin(np.radians(angle)))


class _Footprint(NamedTuple):
    """A segment's shape on the support plane (`_footprints`)."""

    length: float  # [m] the longer side of the minimum-area rectangle of its points on the plane
    width: float  # [m] its shorter side
    height: float  # [m] 98th percentile of the points' heights
    thickness: float  # [m] 5-95 percentile spread along the points' least principal axis (0: one plane)
    normal_up: float  # |vertical component| of that axis: 1 for a horizontal plane, 0 for an upright one
    points: np.ndarray  # up to 400 (right, forward) footprint points (an even thinning)
    chroma: np.ndarray  # (2,) median Lab (a, b) of its grid cells


def _footprints(labels: np.ndarray, Pg: np.ndarray, plane_coords, lab_g: np.ndarray) -> list[_Footprint]:
    """Per segment label 0..K-1: its `_Footprint`."""
    out = []
    for k in range(int(labels.max()) + 1):
        own = labels == k
        chroma = np.median(lab_g[own][:, 1:], axis=0)
        pts = Pg[own]
        pts = pts[np.isfinite(pts[:, 2])]
        if len(pts) < 3:
            out.append(_Footprint(0.0, 0.0, 0.0, 0.0, 0.0, np.zeros((0, 2)), chroma))
            continue
        c = plane_coords(pts)
        xy = c[:, :2].astype(np.float32)
        a, b = sorted(cv2.minAreaRect(xy)[1], reverse=True)
        centred = c - c.mean(axis=0)
        least = np.linalg.eigh(centred.T @ centred)[1][:, 0]
        thickness = float(np.subtract(*np.percentile(centred @ least, [95, 5])))
        height = float(np.percentile(c[:, 2], 98))
        out.append(
            _Footprint(
                float(a),
                float(b),
                height,
                thickness,
                abs(float(least[2])),
                xy[:: max(1, len(xy) // 400)],
                chroma,
            )
        )
    return out


def _join_hinged(
    labels: np.ndarray, Pg: np.ndarray, plane_coords, lab_g: np.ndarray, config: GroundingConfig
) -> np.ndarray:
    """Join a thin upright panel to the flat slab whose edge it stands on (a laptop's screen and base).

    Seen from behind, the screen's back hides the hinge and the base's near half, so the two are apart
    in the image's depth by more than the neighbour test allows and their footprints by more than
    `_FOOTPRINT_JOIN_M`; and they often differ in colour (a black screen on a red base). Any colour joins
    when the pair is adjacent in the image (`_ADJACENT_CELLS`), one is flat (height under
    `_HINGE_SLAB_MAX_H_M`), the other a panel (footprint width under `_HINGE_PANEL_MAX_W_M` and height
    over 2.5 times that), the two footprints are about as long (ratio 0.7-1.4) and come within
    `_HINGE_GAP_M`, or within the panel's height when the two are of one colour. A panel leaning back is
    wider, but flat (thinner than `_HINGE_PANEL_MAX_T_M`) and steep (`_HINGE_PANEL_MAX_NORMAL_UP`).
    """
    K = int(labels.max()) + 1
    if K < 2:
        return labels
    pairs = _adjacent_pairs(labels)
    if not pairs:
        return labels
    feet = _footprints(labels, Pg, plane_coords, lab_g)
    parent = np.arange(K)
    for a, b in sorted(pairs):
        for slab, panel in ((a, b), (b, a)):
            fa, fb = feet[slab], feet[panel]
            if not (len(fa.points) and len(fb.points)) or parent[slab] != slab or parent[panel] != panel:
                continue
            upright = fb.width < _HINGE_PANEL_MAX_W_M and fb.height > 2.5 * fb.width
            leaning = fb.thickness < _HINGE_PANEL_MAX_T_M and fb.normal_up < _HINGE_PANEL_MAX_NORMAL_UP
            if fa.height >= _HINGE_SLAB_MAX_H_M or not (upright or leaning):
                continue
            if not 0.7 <= fb.length / max(fa.length, 1e-6) <= 1.4:
                continue
            gap = _HINGE_GAP_M
            if _shade_distance(fa.chroma, fb.chroma) < config.colour_edge:
                gap = max(gap, fb.height)
            d, _ = cKDTree(fa.points).query(fb.points, k=1, distance_upper_bound=gap)
            if np.min(d) < gap:
                parent[panel] = slab
    if np.all(parent == np.arange(K)):
        return labels
    _, new = np.unique(parent, return_inverse=True)
    return np.where(labels >= 0, new[np.maximum(labels, 0)], -1)


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


def _inner_floor(
    mask: np.ndarray,
    points: np.ndarray,
    lab: np.ndarray,
    ref_lab: np.ndarray,
    plane: SupportPlane,
    config: GroundingConfig,
) -> np.ndarray:
    """Pixels of an object's inner floor that the height cut removed (see `_INNER_FLOOR_SIGMAS`).

    Within the mask's convex outline in the image, pixels with depth that lie on or just above the plane
    (below the height cut) and have the segment's colour (within one `colour_edge`) belong to it when they
    also lie inside the object's footprint on the plane (the convex hull of its points above the cut, seen
    from above): the inside bottom of a bowl or a mug stands only millimetres above the table, within the
    wall. The image outline alone also takes in the table beside a laptop's base or a camera's lens, just as
    low and, for a dark object on a dark table, of its colour too (dev split seed 22: laptop masks up to
    20 % table, boxes 1.3-1.6x too wide); that table lies outside the object's footprint.
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


def segment_objects(
    rgb: np.ndarray,
    point_map: np.ndarray,
    f_px: float,
    plane: SupportPlane | None,
    config: GroundingConfig,
    support_hull: np.ndarray | None = None,
    plane_coords=None,
) -> list[Segment]:
    """Object candidates in an RGB-D frame.

    Args:
        rgb: (H, W, 3) uint8 colour image.
        point_map: (H, W, 3) float64 camera-frame points [m], NaN where there is no depth.
        f_px: mean focal length [px] (sets the expected spacing of neighbouring points).
        plane: the support plane (objects are above it), or None (every valid pixel is a candidate point).
        config: thresholds.
        support_hull: optional (M, 2) float32 polygon in plane (right, forward) coordinates; segments whose
            footprint centre lies outside it (by more than 5 cm) stand on something else and are dropped.
        plane_coords: callable (N, 3) points -> (N, 3) plane coordinates, needed with `support_hull`.

    Returns:
        Segments in raster order of their first grid cell.
    """
    H, W = point_map.shape[:2]
    s = config.segment_stride_px
    Pg = np.ascontiguousarray(point_map[::s, ::s])
    h, w = Pg.shape[:2]
    # colours of the grid cells: the s x s block means (less read noise than single pixels)
    small_rgb = cv2.resize(rgb[: h * s, : w * s], (w, h), interpolation=cv2.INTER_AREA) if s > 1 else rgb
    lab_g = lab_image(small_rgb[:h, :w])
    fg = _above(Pg, plane, config)
    min_cells = max(1, int(np.ceil(config.min_segment_px / (s * s))))
    flat_labels = np.full(fg.shape, -1, dtype=np.int64)
    if plane is not None:
        table_lab = _support_colour(Pg, lab_g, plane, config)
        flat_labels = _flat_objects(fg, Pg, lab_g, plane, config, table_lab)
        if np.any(flat_labels >= 0):  # each is kept when it is big enough for a segment
            big = np.bincount(flat_labels[flat_labels >= 0]) >= min_cells
            flat_labels = np.where(big[np.maximum(flat_labels, 0)], flat_labels, -1)
        fg = _thin_parts(fg, Pg, lab_g, plane, config, table_lab) & (flat_labels < 0)  # one of them
    flat = flat_labels >= 0
    labels, geo = _grid_labels(Pg, lab_g, fg, f_px, s, config)
    heights = None
    if plane is not None:
        with np.errstate(invalid="ignore"):
            heights = np.nan_to_num(Pg @ plane.normal_cam + plane.offset_m, nan=-1.0)
    # cells of attached fragments: painted into their body's mask (the fit sees the handle), but left out of
    # the points that describe the body (footprint and shape family: a box's own stray cells at its far top
    # edge turned it "cylindrical" in a closed-loop episode, tabletop seed 739)
    labels, fragment = _merge_small(labels, geo, min_cells, Pg, heights)
    if np.any(flat):  # each flat object is one segment (`_flat_objects`)
        labels = np.where(flat, flat_labels + int(labels.max()) + 1, labels)
        _, relabel = np.unique(labels, return_inverse=True)
        labels = relabel.reshape(labels.shape) - (1 if np.any(labels < 0) else 0)
    if plane is not None:
        wall = _wall_segments(labels, Pg, plane, config, span_m=_RESPLIT_SPAN_M)
        resplit = np.zeros(labels.shape, dtype=bool)
        if np.any(wall) and config.crease_sigmas < np.inf:
            # a wall or a segment larger than a tabletop object may be objects joined to each other, to
            # a wall or to a robot's base through touching surfaces of similar colour: split it again,
            # this time also at concave creases, and keep the pieces that are not walls themselves
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
        labels = kept
    else:
        background = np.zeros(labels.shape, dtype=bool)
    labels = _join_surfaces(labels, Pg, lab_g, plane_coords if plane is not None else None, config)
    if plane_coords is not None:
        labels = _join_hinged(labels, Pg, plane_coords, lab_g, config)
    K = int(labels.max()) + 1
    if K == 0:
        return []

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
            mask |= _inner_floor(mask, roi_points, lab_roi, ref, plane, config) & ~others
        mask &= ~taken[y0:y1, x0:x1]
        if mask.sum() < config.min_segment_px:
            continue
        full = np.zeros((H, W), dtype=bool)
        full[y0:y1, x0:x1] = mask
        taken[y0:y1, x0:x1] |= mask
        my, mx = np.nonzero(mask)
        box = np.array([x0 + mx.min(), y0 + my.min(), x0 + mx.max(), y0 + my.max()], dtype=np.int64)
        segments.append(Segment(mask=full, points_cam=pts, box_xyxy=box))
    return segments
