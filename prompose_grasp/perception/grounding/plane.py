"""The support plane: sequential RANSAC on a sparse point grid for up to three dominant planes, each refined
by least squares and oriented towards the camera; walls are set aside and the plane with the most support
in the middle of the view, with the scene above it, is the one objects stand on."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

__all__ = [
    "PlaneCandidate",
    "PlaneFrame",
    "choose_support_plane",
    "fit_support_plane",
    "plane_candidates",
    "plane_frame",
    "plane_under_object",
]

log = logging.getLogger(__name__)

#: RANSAC scores hypotheses on at most this many points (a random subset, drawn once): the inlier share
#: of a 40 % plane is then known to +-1 % (binomial, 1 sigma), plenty to rank hypotheses; the winner is
#: re-scored and refined on all points.
_SCORE_SUBSET = 2500

#: A plane must hold at least this share of the sampled points to count as the support (a table seen at a
#: working distance fills far more; a few percent is a wall corner or a box face).
_MIN_INLIER_FRACTION = 0.10

_MIN_POINTS = 30

#: Planes looked for one after another (a table, a wall, a second wall or a large box face).
_MAX_PLANES = 3

#: Points further than this [m] off a plane count as on one side of it (`PlaneCandidate.above_share`): past
#: the inlier band and the noise of a D435 up to ~1.5 m (sigma 9 mm there).
_SIDE_BAND_M = 0.02

#: ... and within this [m] of it: what stands on a support is rarely taller, and a table is higher above the
#: floor (desks 0.72-0.76 m, counters 0.9 m), so the floor seen around a table is no vote against it, while
#: the table 10-40 cm under a box's top face is.
_NEAR_BAND_M = 0.5

#: Sigma [deg] of the centre weighting of plane support (`_centre_weight`).
_CENTRE_SIGMA_DEG = 15.0

#: Two planes whose normals differ by more than this [deg] are a floor-wall pair (a table meets a wall at
#: 90 deg; 50 deg leaves room for a tilted board or a sloped face of a large object).
_WALL_ANGLE_DEG = 50.0

#: The floor's normal must point further up the image than the wall's by this much (of the unit normal's
#: -y component): a camera rolled by up to ~40 deg still sees a table's normal point up the image, a wall's
#: down (the REAL275 frame: table -0.86, wall +0.43).
_UP_MARGIN = 0.3

#: The floor of a floor-wall pair must have at least this share of the wall's central support (a sliver of
#: floor under a wall that fills the view does not make the wall a wall).
_WALL_RIVAL_SHARE = 0.3


#: The support plane's last refits keep the points within this many sigma(z) of the depth noise of it ...
_NOISE_BAND_SIGMAS = 2.5
#: ... and at least this close [m] (a near table's sigma is ~1 mm; the plane's own error is a few mm).
_NOISE_BAND_MIN_M = 0.004


def _refine(points: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (total least squares: smallest principal axis) through the inlier points."""
    P = points[inliers]
    c = P.mean(axis=0)
    # 3x3 scatter instead of an SVD of the (N, 3) matrix: the same smallest eigenvector, N times cheaper
    _, vecs = np.linalg.eigh((P - c).T @ (P - c))
    n = vecs[:, 0]
    return n, -float(n @ c)


def _refit_in_band(
    points: np.ndarray, n: np.ndarray, d: float, band: float | np.ndarray, rounds: int
) -> tuple[np.ndarray, float] | None:
    """The plane (n, d) refitted `rounds` times (`_refine`) on the points within `band` [m] of it (one
    distance, or one per point); None when fewer than 3 points are in. The result's sign is `_refine`'s."""
    for _ in range(rounds):
        inliers = np.abs(points @ n + d) < band
        if inliers.sum() < 3:
            return None
        n, d = _refine(points, inliers)
    return n, d


def _ransac_plane(
    points: np.ndarray, rng: np.random.Generator, config: GroundingConfig
) -> tuple[np.ndarray, float] | None:
    """The plane with the most inliers among `config.ransac_iterations` 3-point hypotheses, refined twice."""
    N = len(points)
    if N < _MIN_POINTS:
        return None
    subset = points if N <= _SCORE_SUBSET else points[rng.choice(N, _SCORE_SUBSET, replace=False)]
    idx = rng.integers(0, N, size=(config.ransac_iterations, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not np.any(ok):
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, a[ok])
    counts = (np.abs(subset @ normals.T + offsets) < config.ransac_inlier_m).sum(axis=0)
    best = int(np.argmax(counts))
    # refit on the inliers, then once more on the refit's inliers
    refit = _refit_in_band(points, normals[best], float(offsets[best]), config.ransac_inlier_m, 2)
    if refit is None:
        return None
    n, d = refit
    n = n / np.linalg.norm(n)
    if d < 0:  # the camera (origin) must be on the positive side: normal points "up" towards it
        n, d = -n, -d
    return n, float(d)


@dataclass(frozen=True)
class PlaneCandidate:
    """One of the dominant planes of a frame and what `choose_support_plane` judged it by.

    Attributes:
        plane: the plane (normal towards the camera), `inlier_fraction` of all the points.
        central_support: inliers weighted by `_centre_weight` (their direction's angle from the optical axis),
            as a share of all the points: a table under the objects fills the middle of the view.
        above_share: of the points off the plane by more than `_SIDE_BAND_M` and less than `_NEAR_BAND_M`,
            the share on the camera's side:
            objects stand on a support, so most of what is not the plane is above it (a box's top face has
            the scene below it).
        wall: True when another candidate at more than `_WALL_ANGLE_DEG` to it has its normal pointing
            further up the image (see `choose_support_plane`).
    """

    plane: SupportPlane
    central_support: float
    above_share: float
    wall: bool = False

    @property
    def score(self) -> float:
        """central_support x (0.25 + 0.75 above_share); walls score 0."""
        return 0.0 if self.wall else self.central_support * (0.25 + 0.75 * self.above_share)


def _centre_weight(points: np.ndarray) -> np.ndarray:
    """(N,) Gaussian weight of each point's viewing direction's angle from the optical axis (sigma 15 deg).

    The camera is pointed at the objects, and the objects stand on the support, so the support fills the
    middle of the view; 15 deg is half the half-field of a 58 deg camera: points at the image's edge count a
    fifth, at the corners a tenth.
    """
    z = np.maximum(points[:, 2], 1e-9)
    tan2 = (points[:, 0] ** 2 + points[:, 1] ** 2) / z**2
    theta = np.arctan(np.sqrt(tan2))
    return np.exp(-0.5 * (theta / np.radians(_CENTRE_SIGMA_DEG)) ** 2)


def plane_candidates(points_cam: np.ndarray, config: GroundingConfig) -> list[PlaneCandidate]:
    """Up to `_MAX_PLANES` dominant planes, found one after another (each on the points the previous left).

    Each holds at least `_MIN_INLIER_FRACTION` of all the points. Deterministic (seeded by `config.seed`).
    """
    P = np.asarray(points_cam, dtype=np.float64)
    N = len(P)
    if N < _MIN_POINTS:
        return []
    rng = np.random.default_rng(config.seed)
    w = _centre_weight(P)
    free = np.ones(N, dtype=bool)
    found: list[PlaneCandidate] = []
    for _ in range(_MAX_PLANES):
        rest = np.nonzero(free)[0]
        fit = _ransac_plane(P[rest], rng, config)
        if fit is None:
            break
        n, d = fit
        h = P @ n + d
        inliers = np.abs(h) < config.ransac_inlier_m
        fraction = float(inliers.mean())
        if fraction < _MIN_INLIER_FRACTION:
            break
        off = (np.abs(h) > _SIDE_BAND_M) & (np.abs(h) < _NEAR_BAND_M)
        above = float((h[off] > 0).mean()) if np.any(off) else 1.0
        plane = SupportPlane(normal_cam=n, offset_m=d, inlier_fraction=fraction)
        found.append(PlaneCandidate(plane, float(w[inliers].sum() / N), above))
        free &= ~inliers
    # walls: of two planes at a large angle, the one whose normal points less up the image (image up is
    # camera -y) is a wall or a box side when the other is a floor or table
    out = []
    for i, c in enumerate(found):
        n = c.plane.normal_cam
        wall = any(
            abs(float(n @ o.plane.normal_cam)) < np.cos(np.radians(_WALL_ANGLE_DEG))
            and -o.plane.normal_cam[1] > -n[1] + _UP_MARGIN
            and o.central_support >= _WALL_RIVAL_SHARE * c.central_support
            for j, o in enumerate(found)
            if j != i
        )
        out.append(PlaneCandidate(c.plane, c.central_support, c.above_share, wall))
    return out


def choose_support_plane(candidates: list[PlaneCandidate]) -> SupportPlane | None:
    """The candidate with the highest `PlaneCandidate.score` (None without candidates).

    When every candidate is a wall by the rule (cannot happen with two: the one further up is not), the
    largest central support wins.
    """
    if not candidates:
        return None
    scores = [c.score for c in candidates]
    if max(scores) <= 0.0:
        scores = [c.central_support for c in candidates]
    return candidates[int(np.argmax(scores))].plane


def fit_support_plane(points_cam: np.ndarray, config: GroundingConfig) -> SupportPlane | None:
    """The plane the objects stand on, with its normal pointing to the camera's side.

    Up to three dominant planes are found by sequential RANSAC (`plane_candidates`); walls (a plane at more
    than 50 deg to another whose normal points further up the image) are set aside, and the one with the
    most support near the middle of the view, most of the rest of the scene above it, wins
    (`PlaneCandidate.score`).

    Args:
        points_cam: (N, 3) float64 finite camera-frame points [m] (a strided sample of the depth image).
        config: `ransac_iterations`, `ransac_inlier_m` and `seed` are used.

    Returns:
        The plane, or None when there are too few points or no plane holds `_MIN_INLIER_FRACTION` of them.
        Deterministic: the hypotheses come from `numpy.random.default_rng(config.seed)`.
    """
    plane = choose_support_plane(plane_candidates(points_cam, config))
    if plane is None:
        log.debug("no support plane among %d points", len(points_cam))
        return None
    return _noise_band_refit(np.asarray(points_cam, dtype=np.float64), plane, config)


def _noise_band_refit(points: np.ndarray, plane: SupportPlane, config: GroundingConfig) -> SupportPlane:
    """The support refitted three times on the points within the sensor's own noise band of it
    (`_NOISE_BAND_SIGMAS` sigma(z), clipped to [`_NOISE_BAND_MIN_M`, `ransac_inlier_m`]).

    The fixed RANSAC band also holds the top of flat objects 1-2 cm high near the camera (a laptop's base),
    whose points tilted the table (dev 22 / 23: 90th percentile of the tilt against the objects' true up
    0.43 / 0.88 deg -> 0.03 / 0.04 deg). Only the chosen support is refitted: the candidates' ranking and
    the points each takes from the next are the fixed band's.
    """
    band = np.clip(
        _NOISE_BAND_SIGMAS * config.sigma_m(points[:, 2]), _NOISE_BAND_MIN_M, config.ransac_inlier_m
    )
    refit = _refit_in_band(points, plane.normal_cam, plane.offset_m, band, 3)
    if refit is None:
        return plane
    n, d = refit
    if n @ plane.normal_cam < 0.0:  # keep the normal on the camera's side
        n, d = -n, -d
    return SupportPlane(
        normal_cam=n / np.linalg.norm(n), offset_m=float(d), inlier_fraction=plane.inlier_fraction
    )


#: An object whose lowest points (2nd percentile of their height) lie more than this [m] above the support
#: plane does not stand on it: the bottom edge of a resting object is seen within 1-2 cm of its support (depth
#: noise, a rounded rim), and 5 cm leaves room for a bottom hidden behind something low in front.
_REST_GAP_M = 0.05

#: Share of the object's surroundings that must lie on a plane for it to be there (`plane_under_object`):
#: a table top round an object fills far more of them; a few percent is a neighbour's face.
_SURROUNDING_SHARE = 0.10

#: The surroundings sampled by `plane_under_object` are at most this many pixels (an even stride).
_SURROUNDING_PIXELS = 6000


def plane_under_object(
    plane: SupportPlane,
    points_cam: np.ndarray,
    depth_m: np.ndarray,
    intrinsics: CameraIntrinsics,
    mask: np.ndarray,
) -> SupportPlane:
    """The plane the object of `mask` stands on: `plane` (the frame's support), or a surface parallel to it
    right under the object.

    The frame's dominant plane is not always the object's support: a small table seen over a larger floor
    gives the floor, and a box fitted down to it grows by the table's height. When the object's lowest
    points lie more than `_REST_GAP_M` above `plane`, its surroundings (the mask's box grown by its own
    width and height each side, outside the mask) are looked at: the densest 2 cm slab of heights between
    `plane` and the object's lowest points is the support (a table top, with `plane`'s normal) when it holds
    at least `_SURROUNDING_SHARE` of the surroundings, more of them than `plane` itself does, and the
    object rises more than `_REST_GAP_M` above it. Otherwise `plane` is kept: the object's bottom is only
    hidden (behind something low in front of it), nothing under it is seen, or the object is level with the
    surface round it (a carton's top among its neighbours' in a layer seen from above).

    Args:
        plane: the frame's support plane (`fit_support_plane`).
        points_cam: (N, 3) the object's points [m], camera frame (the mask back-projected), N > 0.
        depth_m, intrinsics: the frame's depth image and camera.
        mask: (H, W) bool, the object's pixels.
    """
    n, d = plane.normal_cam, plane.offset_m
    low, top = np.percentile(points_cam @ n + d, [2.0, 98.0])
    if low <= _REST_GAP_M:
        return plane
    ys, xs = np.nonzero(mask)
    h_img, w_img = mask.shape
    bw, bh = xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
    around = np.zeros_like(mask)
    around[max(0, ys.min() - bh) : min(h_img, ys.max() + bh + 1),
           max(0, xs.min() - bw) : min(w_img, xs.max() + bw + 1)] = True  # fmt: skip
    around &= ~mask
    stride = max(1, int(np.sqrt(np.count_nonzero(around) / _SURROUNDING_PIXELS)))
    sparse = np.zeros_like(mask)
    sparse[::stride, ::stride] = True
    h = back_project(depth_m, intrinsics, mask=around & sparse) @ n + d
    between = h[(h > _SIDE_BAND_M) & (h < low + _SIDE_BAND_M)]
    if len(between) < _SURROUNDING_SHARE * len(h):
        return plane
    counts, edges = np.histogram(between, bins=np.arange(_SIDE_BAND_M, low + 2.0 * _SIDE_BAND_M, 0.01))
    peak = 0.5 * (edges[np.argmax(counts)] + edges[np.argmax(counts) + 1])
    on = np.abs(h - peak) < 0.01
    if np.mean(on) < _SURROUNDING_SHARE or np.count_nonzero(on) <= np.count_nonzero(np.abs(h) < _SIDE_BAND_M):
        return plane  # no surface under the object, or the frame's plane shows more round it
    height = float(np.median(h[on]))
    if top - height < _REST_GAP_M:
        # the object does not rise from that surface, it is level with it: a carton's top seen from above
        # among its neighbours' tops in the same layer, whose support is not seen
        return plane
    log.debug("object %.2f m above the frame's plane: its support is %.3f m above it", low, height)
    return SupportPlane(normal_cam=n, offset_m=d - height, inlier_fraction=float(np.mean(on)))


class PlaneFrame:
    """Axes on the support plane as the camera sees it (all (3,) unit vectors in the camera frame).

    right: the camera's +x (image right) projected onto the plane; forward: the viewing direction projected
    onto the plane (away from the camera, "behind"); up: the plane normal. Coordinates of a point are
    (right, forward, up) [m] relative to the camera's foot on the plane.
    """

    def __init__(self, plane: SupportPlane):
        up = plane.normal_cam
        z = np.array([0.0, 0.0, 1.0])
        forward = z - (z @ up) * up
        if np.linalg.norm(forward) < 1e-6:  # looking straight down: image "up" (-y) is forward
            y = np.array([0.0, -1.0, 0.0])
            forward = y - (y @ up) * up
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)  # forward x up is right-handed (right, forward, up)
        if right[0] < 0:  # keep "right" agreeing with the image's right
            right = -right
        self.right, self.forward, self.up = right, forward, up
        self.origin_cam = -plane.offset_m * up  # the camera's foot on the plane
        self.R_cam_plane = np.stack([right, forward, up], axis=1)

    def coords(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) (right, forward, height) coordinates [m] of (N, 3) camera-frame points."""
        return (np.asarray(points_cam, dtype=np.float64) - self.origin_cam) @ self.R_cam_plane


def plane_frame(plane: SupportPlane) -> PlaneFrame:
    """The (right, forward, up) frame of `plane` as seen from the camera."""
    return PlaneFrame(plane)
