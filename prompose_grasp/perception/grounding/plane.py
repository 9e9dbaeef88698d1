"""The support plane: RANSAC on a sparse point grid, refined by least squares, oriented towards the camera."""

from __future__ import annotations

import logging

import numpy as np

from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

__all__ = ["PlaneFrame", "fit_support_plane", "plane_frame"]

log = logging.getLogger(__name__)

#: RANSAC scores hypotheses on at most this many points (a random subset, drawn once): the inlier share
#: of a 40 % plane is then known to +-1 % (binomial, 1 sigma), plenty to rank hypotheses; the winner is
#: re-scored and refined on all points.
_SCORE_SUBSET = 2500

#: A plane must hold at least this share of the sampled points to count as the support (a table seen at a
#: working distance fills far more; a few percent is a wall corner or a box face).
_MIN_INLIER_FRACTION = 0.10

_MIN_POINTS = 30


def _refine(points: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (total least squares: smallest principal axis) through the inlier points."""
    P = points[inliers]
    c = P.mean(axis=0)
    # 3x3 scatter instead of an SVD of the (N, 3) matrix: the same smallest eigenvector, N times cheaper
    _, vecs = np.linalg.eigh((P - c).T @ (P - c))
    n = vecs[:, 0]
    return n, -float(n @ c)


def fit_support_plane(points_cam: np.ndarray, config: GroundingConfig) -> SupportPlane | None:
    """The dominant plane of a point set, with its normal pointing to the camera's side.

    Args:
        points_cam: (N, 3) float64 finite camera-frame points [m] (a strided sample of the depth image).
        config: `ransac_iterations`, `ransac_inlier_m` and `seed` are used.

    Returns:
        The plane, or None when there are too few points or no plane holds `_MIN_INLIER_FRACTION` of them.
        Deterministic: the hypotheses come from `numpy.random.default_rng(config.seed)`.
    """
    N = len(points_cam)
    if N < _MIN_POINTS:
        return None
    rng = np.random.default_rng(config.seed)
    subset = points_cam if N <= _SCORE_SUBSET else points_cam[rng.choice(N, _SCORE_SUBSET, replace=False)]
    idx = rng.integers(0, N, size=(config.ransac_iterations, 3))
    a, b, c = points_cam[idx[:, 0]], points_cam[idx[:, 1]], points_cam[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not np.any(ok):
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, a[ok])
    counts = (np.abs(subset @ normals.T + offsets) < config.ransac_inlier_m).sum(axis=0)
    best = int(np.argmax(counts))
    n, d = normals[best], float(offsets[best])
    for _ in range(2):  # refit on the inliers, then once more on the refit's inliers
        inliers = np.abs(points_cam @ n + d) < config.ransac_inlier_m
        if inliers.sum() < 3:
            return None
        n, d = _refine(points_cam, inliers)
    inliers = np.abs(points_cam @ n + d) < config.ransac_inlier_m
    fraction = float(inliers.mean())
    if fraction < _MIN_INLIER_FRACTION:
        log.debug("no support plane: best plane holds %.1f %% of the points", 100 * fraction)
        return None
    if d < 0:  # the camera (origin) must be on the positive side: normal points "up" towards it
        n, d = -n, -d
    return SupportPlane(normal_cam=n / np.linalg.norm(n), offset_m=d, inlier_fraction=fraction)


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
