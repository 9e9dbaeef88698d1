"""Which grid cells stand on the support: the height cut, thin parts just under it, objects lying flat, and
the concave creases where touching objects meet. Colours are compared in CIE Lab (`lab_image`)."""

from __future__ import annotations

import cv2
import numpy as np

from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

#: A thin part under the height cut (a laptop's 12-22 mm base at 1 m, where the cut is 2.5 sigma = 12 mm)
#: still counts as above the support where it stands this many sigma(z) and at least `_THIN_MIN_M` up, is
#: not of the support's colour, and joins a cell above the cut through such cells (`_thin_parts`).
_THIN_SIGMAS = 1.5
_THIN_MIN_M = 0.005
#: An object lower than the cut everywhere (`_flat_objects`): at least this many grid cells, their mean
#: height this many standard errors above the plane (and `_THIN_MIN_M`). Table noise reads a piece's mean
#: that high by chance about once in three million; a plane fitted a fraction of a degree off reads a few
#: millimetres high far away, which the 5 mm floor holds. A knife lying 1.3 m away keeps depth on 30-50 of
#: its cells, whose mean reads 6-8 mm (its blade's edge pixels read the table), 5-6 standard errors up.
_FLAT_MIN_CELLS = 20
_FLAT_SIGMAS = 5.0
_FLAT_MAX_FG_SHARE = 0.3


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


def _foreground(
    Pg: np.ndarray, lab_g: np.ndarray, plane: SupportPlane | None, config: GroundingConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The grid cells `Pg` (h, w, 3) of standing objects ((h, w) bool: above the height cut, and the thin
    parts under it), and the (h, w) int labels 0..F-1 (-1 elsewhere) of objects lying flat; no flat objects
    and every valid cell without a plane."""
    fg = _above(Pg, plane, config)
    flat_labels = np.full(fg.shape, -1, dtype=np.int64)
    if plane is None:
        return fg, flat_labels
    table_lab = _support_colour(Pg, lab_g, plane, config)
    # each is kept whatever its count of cells with depth: depth drops out over much of a thin dark or
    # shiny object, and its mask, filled with the pixels of its colour, is judged by size when painted
    flat_labels = _flat_objects(fg, Pg, lab_g, plane, config, table_lab)
    fg = _thin_parts(fg, Pg, lab_g, plane, config, table_lab) & (flat_labels < 0)  # one of them
    return fg, flat_labels
