"""What a candidate looks like, in words: dominant colour, size class, shape family, and a description.

Colour. Every pixel of the mask is named from its HSV value with a fixed palette (thresholds below; hue in
degrees, saturation and value in [0, 1]):

| name | rule |
|---|---|
| black | V < 0.16 |
| white | S < 0.18 and V > 0.72 |
| grey | S < 0.18 otherwise |
| brown | hue 8-45 deg and (S < 0.6 or V < 0.5): orange hues, dull or dark |
| red | hue < 14 or >= 340 |
| orange | 14-42 |
| yellow | 42-70 |
| green | 70-165 |
| cyan | 165-195 |
| blue | 195-260 |
| purple | 260-290 |
| pink | 290-340 |

The candidate's colour is the most common name; `colour_fractions` keeps the share of every name so that a
prompt's colour word can be checked against all of them (a shaded red mug is mostly "red", partly "brown").

Size class, from the largest visible extent L (support-plane frame): small L < 0.09 m (a ball, a cup, a
mug), medium 0.09 m <= L < 0.22 m (a can, a bottle, a cereal box), large L >= 0.22 m (a laptop, a carton).

Shape family, from the extents in the support-plane frame (footprint length a >= width b, height h) and
two quick fits (all ratios are of visible extents, which for round things underestimate the depth):

1. elongated: a >= 2.5 max(b, h) (a tube or a bottle lying down);
2. sphere: an algebraic sphere fit to the points has RMS residual < 12 % of its radius and a diameter
   within 30 % of both h and a;
3. flat: h < 0.4 a (a plate, a tray, a laptop's base, a shallow bowl);
4. cylinder: a circle fitted (robustly, so a mug's handle drops out) to the side points (heights 15-85 %)
   projected onto the plane explains them at least twice as well as the edges of their minimum-area
   rectangle do, with a median residual < max(10 % of its radius, 5 mm of sensor noise) and a radius
   between 0.25 a and 0.8 a (a can, a mug, a cup);
5. box: the side points' median distance to the nearest edge of their minimum-area rectangle is < 25 % of
   b (sensor noise thickens a face seen at 1 m by about a centimetre);
6. irregular: none of the above.

Top-height histogram (`top_height_histogram`), a view-tolerant shape signature that a family's mesh gives
too: the footprint is cut into cells of a tenth of its length, each cell keeps its highest point, and the
cells' top heights, as fractions of the object's height, are histogrammed in `HEIGHT_BINS` equal bins. Seen
from above (the tabletop camera's 30-65 deg elevation sees the tops) a box or a can is all "top" (last
bin), a laptop mostly "low" (its base) with a strip of "top" (the screen's edge), a bottle has most of its
footprint at shoulder height and a little at the top (the neck), a camera's body is lower than its
viewfinder hump, a mug's opening shows its inside lower than the rim. It does not depend on the object's
yaw or metric size, and occlusion removes cells without changing the heights of the others.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "HEIGHT_BINS",
    "PALETTE",
    "SHAPE_FAMILIES",
    "SHAPE_PHRASES",
    "SIZE_CLASSES",
    "colour_names",
    "describe_text",
    "dominant_colour",
    "shape_family",
    "size_class",
    "top_height_histogram",
]

#: Bins of the top-height histogram (fractions of the height, equal widths over [0, 1]).
HEIGHT_BINS = 6

#: Footprint cells of the top-height histogram are this fraction of the footprint length: ~10 x 10 cells,
#: each holding tens of grid points of a 10 cm object seen at 0.8 m (3 mm apart at a 2 px stride).
_HEIGHT_CELL_FRACTION = 0.1

PALETTE: tuple[str, ...] = (
    "red",
    "orange",
    "yellow",
    "green",
    "cyan",
    "blue",
    "purple",
    "pink",
    "brown",
    "black",
    "white",
    "grey",
)

#: (name, upper bound of the largest extent [m]); the last class has no bound.
SIZE_CLASSES: tuple[tuple[str, float], ...] = (("small", 0.09), ("medium", 0.22), ("large", float("inf")))

SHAPE_FAMILIES: tuple[str, ...] = ("box", "cylinder", "sphere", "flat", "elongated", "irregular")

#: How a family reads in the generated description.
SHAPE_PHRASES: dict[str, str] = {
    "box": "box-shaped",
    "cylinder": "cylindrical",
    "sphere": "round ball-shaped",
    "flat": "flat",
    "elongated": "long thin",
    "irregular": "irregularly shaped",
}

# hue upper bounds [deg] of the chromatic names, in order (red wraps around 360)
_HUE_BOUNDS = ((14.0, "red"), (42.0, "orange"), (70.0, "yellow"), (165.0, "green"), (195.0, "cyan"),
               (260.0, "blue"), (290.0, "purple"), (340.0, "pink"), (360.0, "red"))  # fmt: skip
_INDEX = {name: i for i, name in enumerate(PALETTE)}


def colour_names(rgb_pixels: np.ndarray) -> np.ndarray:
    """(N,) int palette index of each of (N, 3) uint8 RGB pixels (see the module table)."""
    px = np.ascontiguousarray(rgb_pixels, dtype=np.uint8).reshape(-1, 1, 3)
    hsv = cv2.cvtColor(px, cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(np.float32)
    hue = hsv[:, 0] * (360.0 / 256.0)
    sat = hsv[:, 1] / 255.0
    val = hsv[:, 2] / 255.0
    out = np.empty(len(hue), dtype=np.int64)
    lo = 0.0
    for hi, name in _HUE_BOUNDS:
        out[(hue >= lo) & (hue < hi)] = _INDEX[name]
        lo = hi
    out[(hue >= 8.0) & (hue < 45.0) & ((sat < 0.6) | (val < 0.5))] = _INDEX["brown"]
    grey = sat < 0.18
    out[grey] = _INDEX["grey"]
    out[grey & (val > 0.72)] = _INDEX["white"]
    out[val < 0.16] = _INDEX["black"]
    return out


def dominant_colour(rgb_pixels: np.ndarray) -> tuple[str, np.ndarray, dict[str, float]]:
    """Dominant palette name, its median (3,) uint8 RGB, and the share of every palette name.

    Args:
        rgb_pixels: (N, 3) uint8, N >= 1.
    """
    names = colour_names(rgb_pixels)
    counts = np.bincount(names, minlength=len(PALETTE)).astype(np.float64)
    best = int(np.argmax(counts))
    rgb = np.median(np.asarray(rgb_pixels).reshape(-1, 3)[names == best], axis=0).astype(np.uint8)
    fractions = {name: float(c / counts.sum()) for name, c in zip(PALETTE, counts)}
    return PALETTE[best], rgb, fractions


def size_class(extent_m: np.ndarray) -> str:
    """ "small" | "medium" | "large" from the largest of the (3,) extents [m] (`SIZE_CLASSES`)."""
    largest = float(np.max(extent_m))
    for name, bound in SIZE_CLASSES:
        if largest < bound:
            return name
    return SIZE_CLASSES[-1][0]


def _fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Algebraic (Kasa) circle fit of (N, 2) points, refit once without outliers: centre, radius, RMS."""
    keep = np.ones(len(xy), dtype=bool)
    centre, r, rms = xy.mean(axis=0), 0.0, np.inf
    for _ in range(2):
        P = xy[keep]
        if len(P) < 5:
            break
        A = np.column_stack([2.0 * P, np.ones(len(P))])
        sol, *_ = np.linalg.lstsq(A, (P**2).sum(axis=1), rcond=None)
        centre = sol[:2]
        r = float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))
        res = np.abs(np.linalg.norm(xy - centre, axis=1) - r)
        rms = float(np.sqrt(np.mean(res[keep] ** 2)))
        keep = res < max(3.0 * np.median(res), 1e-4)  # drop a mug's handle, stray edge pixels
    return centre, r, rms


def _fit_sphere(P: np.ndarray) -> tuple[float, float]:
    """Algebraic sphere fit of (N, 3) points: radius and RMS residual [m]."""
    A = np.column_stack([2.0 * P, np.ones(len(P))])
    sol, *_ = np.linalg.lstsq(A, (P**2).sum(axis=1), rcond=None)
    c = sol[:3]
    r = float(np.sqrt(max(sol[3] + c @ c, 0.0)))
    res = np.linalg.norm(P - c, axis=1) - r
    return r, float(np.sqrt(np.mean(res**2)))


#: Median circle residual that sensor noise alone leaves on a round object's side points [m] (RealSense-like
#: noise at ~1 m, measured on the tabletop scene's soda cans: 3.2-3.8 mm).
CYLINDER_NOISE_FLOOR_M = 0.005


def shape_family(coords: np.ndarray, extent_m: np.ndarray) -> str:
    """Shape family of a candidate (module docstring, rules 1-6).

    Args:
        coords: (N, 3) float64 points in the support-plane frame (right, forward, height) [m].
        extent_m: (3,) footprint length a >= width b, height h [m].
    """
    a, b, h = (float(x) for x in extent_m)
    if len(coords) < 20 or a <= 0:
        return "irregular"
    if a >= 2.5 * max(b, h):
        return "elongated"
    r, rms = _fit_sphere(coords)
    if r > 0 and rms < 0.12 * r and abs(2 * r - h) < 0.3 * h and abs(2 * r - a) < 0.3 * a:
        return "sphere"
    if h < 0.4 * a:
        return "flat"
    heights = coords[:, 2]
    side = coords[(heights > 0.15 * h) & (heights < 0.85 * h), :2]
    if len(side) < 10:
        side = coords[:, :2]
    centre, rc, _ = _fit_circle(side)
    med_c = float(np.median(np.abs(np.linalg.norm(side - centre, axis=1) - rc)))
    med_r = _rect_median(side)
    # The median residual is allowed the depth noise's floor (a 3 cm can at a metre leaves 3-4 mm, over 10 %
    # of its radius), and the circle must beat the rectangle clearly (half its residual: a box's sides are on
    # its rectangle, a noisy corner view is not twice as far from it as from a circle). The fit of half an arc
    # seen through that noise comes out small (a 33 mm can: 20-22 mm), hence a quarter of the footprint.
    if (
        rc > 0
        and med_c < max(0.1 * rc, CYLINDER_NOISE_FLOOR_M)
        and med_c < 0.5 * med_r
        and 0.25 * a <= rc <= 0.8 * a
    ):
        return "cylinder"
    if med_r < 0.25 * max(b, 1e-3):
        return "box"
    return "irregular"


def _rect_median(xy: np.ndarray) -> float:
    """Median distance [m] of (N, 2) points to the nearest edge of their minimum-area rectangle."""
    corners = cv2.boxPoints(cv2.minAreaRect(xy.astype(np.float32))).astype(np.float64)
    d_edge = np.full(len(xy), np.inf)
    for i in range(4):
        p, q = corners[i], corners[(i + 1) % 4]
        t = np.clip(((xy - p) @ (q - p)) / max((q - p) @ (q - p), 1e-12), 0.0, 1.0)
        d_edge = np.minimum(d_edge, np.linalg.norm(xy - (p + t[:, None] * (q - p)), axis=1))
    return float(np.median(d_edge))


def top_height_histogram(coords: np.ndarray, height_m: float, length_m: float) -> np.ndarray:
    """(HEIGHT_BINS,) float64 shares (sum 1) of footprint cells by their top height (module docstring).

    Args:
        coords: (N, 3) float64 points in the support-plane frame (right, forward, height) [m].
        height_m: the object's height [m] (top heights are fractions of it; higher ones go to the last bin).
        length_m: its footprint length [m] (sets the cell size).

    Returns all zeros for an empty point set.
    """
    out = np.zeros(HEIGHT_BINS)
    P = np.asarray(coords, dtype=np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) == 0 or not (height_m > 0 and length_m > 0):
        return out
    ij = np.floor(P[:, :2] / (_HEIGHT_CELL_FRACTION * length_m)).astype(np.int64)
    ij -= ij.min(axis=0)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    top = np.full(int(key.max()) + 1, -np.inf)
    np.maximum.at(top, key, P[:, 2])  # each cell's highest point (3x faster than sorting by cell)
    top = top[np.isfinite(top)] / height_m
    bins = np.clip((top * HEIGHT_BINS).astype(np.int64), 0, HEIGHT_BINS - 1)
    out += np.bincount(bins, minlength=HEIGHT_BINS)
    return out / out.sum()


def describe_text(size: str, colour: str, family: str) -> str:
    """The phrase scored against the prompt, e.g. "a small yellow cylindrical object"."""
    return f"a {size} {colour} {SHAPE_PHRASES[family]} object"
