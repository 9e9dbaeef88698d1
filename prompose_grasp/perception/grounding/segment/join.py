"""Segments of one object joined: two surfaces of one colour on one footprint (the outside of a bowl and its
inside, `_join_surfaces`), and a thin upright panel with the flat slab it stands on (a laptop's screen and
base, `_join_hinged`)."""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.perception.grounding.types import GroundingConfig

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
#: A hinge is a line that the panel and the slab share, so the panel's footprint runs along the slab's
#: edge: their footprints' long axes are parallel within this [deg] (the minimum-area rectangle of a noisy,
#: partly hidden base turns by a few degrees). A box standing beside a banana lying at an angle is no hinge
#: (a real frame: 52 deg apart, joined before, as a laptop).
_HINGE_MAX_ANGLE_DEG = 20.0


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
    axis: np.ndarray  # (2,) unit direction of the rectangle's longer side on the plane
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
            out.append(_Footprint(0.0, 0.0, 0.0, np.array([1.0, 0.0]), 0.0, 0.0, np.zeros((0, 2)), chroma))
            continue
        c = plane_coords(pts)
        xy = c[:, :2].astype(np.float32)
        _, (w, h), angle = cv2.minAreaRect(xy)
        a, b = max(w, h), min(w, h)
        t = np.radians(angle) + (0.0 if w >= h else 0.5 * np.pi)  # cv2's angle is that of the side w
        centred = c - c.mean(axis=0)
        least = np.linalg.eigh(centred.T @ centred)[1][:, 0]
        thickness = float(np.subtract(*np.percentile(centred @ least, [95, 5])))
        height = float(np.percentile(c[:, 2], 98))
        out.append(
            _Footprint(
                float(a),
                float(b),
                height,
                np.array([np.cos(t), np.sin(t)]),
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
    over 2.5 times that), the two footprints are about as long (ratio 0.7-1.4) and parallel
    (`_HINGE_MAX_ANGLE_DEG`: the panel runs along the slab's edge) and come within `_HINGE_GAP_M`, or
    within the panel's height when the two are of one colour. A panel leaning back is
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
            if abs(float(fa.axis @ fb.axis)) < np.cos(np.radians(_HINGE_MAX_ANGLE_DEG)):
                continue  # not along the slab's edge: no hinge
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
