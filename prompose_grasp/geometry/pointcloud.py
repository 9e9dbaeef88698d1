"""Point clouds from depth images, farthest point sampling, the paper's robust PCA descriptor (section 3.5).

Depth images are (H, W) floating arrays in metres along the camera z axis (OpenCV frame: x right, y down,
z forward). A pixel has no reading when its depth is 0, negative, NaN, inf, or at most `MIN_VALID_DEPTH_M`.
Pixel (row v, column u) has its centre at image coordinates (u, v) (see `camera.py`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.tolerances import DEPTH_MEDIAN_RANGE_M, MIN_VALID_DEPTH_M

__all__ = [
    "RobustDescriptor",
    "back_project",
    "check_depth_units",
    "depth_to_point_map",
    "farthest_point_sampling",
    "masked_median_depth",
    "outline_corrected_points",
    "robust_descriptor",
    "valid_depth_mask",
]


def _depth(depth: ArrayLike, intrinsics: CameraIntrinsics) -> np.ndarray:
    if not isinstance(intrinsics, CameraIntrinsics):
        raise InvalidInputError(f"intrinsics must be a CameraIntrinsics, got {type(intrinsics).__name__}")
    D = np.asarray(depth)
    if D.ndim != 2:
        raise InvalidInputError(f"depth must be an (H, W) image in metres, got shape {D.shape}")
    if not np.issubdtype(D.dtype, np.floating):
        raise InvalidInputError(
            f"depth must be floating-point metres, got dtype {D.dtype}; convert integer depth images first "
            "(e.g. uint16 millimetres: depth_m = raw.astype(np.float32) * 0.001)"
        )
    if D.shape != intrinsics.shape:
        raise InvalidInputError(
            f"depth has shape {D.shape} but the intrinsics are for (height, width) = {intrinsics.shape}"
        )
    return D


def _pixel_mask(mask: ArrayLike, shape: tuple[int, ...]) -> np.ndarray:
    """(H, W) bool of a pixel selection given as bool or integer (nonzero = selected) of the depth's shape."""
    M = np.asarray(mask)
    if M.shape != shape:
        raise InvalidInputError(f"mask has shape {M.shape}, depth has {shape}; they must match")
    if not (M.dtype == np.bool_ or np.issubdtype(M.dtype, np.integer)):
        raise InvalidInputError(f"mask must be bool (or integer, nonzero = selected), not {M.dtype}")
    return M.astype(bool, copy=False)


def valid_depth_mask(depth: ArrayLike) -> np.ndarray:
    """(H, W) bool: pixels with a depth reading (finite and > MIN_VALID_DEPTH_M)."""
    D = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(D) & (D > MIN_VALID_DEPTH_M)


#: `check_depth_units` takes the median of about this many readings (an even stride over the image): the
#: median of 20,000 samples is within a fraction of a percent of the whole image's, at 1/15 the cost at VGA.
_MEDIAN_SAMPLES = 20_000


def check_depth_units(depth: ArrayLike, name: str = "depth_m") -> None:
    """Refuse a depth image that no RGB-D camera measures in metres.

    The median of the image's readings (finite values farther than `MIN_VALID_DEPTH_M` from 0, of either
    sign) must lie in `DEPTH_MEDIAN_RANGE_M` (5 cm - 10 m: the range of consumer RGB-D cameras). Single
    readings are not judged: a negative or far one is "no reading" (`valid_depth_mask`), as sensor noise
    makes them; a whole image out of range is a unit or sign mistake. An image without a single reading
    passes (whether one may be used is the caller's call).

    Raises:
        InvalidInputError: the median is negative (a sign mistake) or outside the range; a median that is a
            plausible distance in millimetres says so ("depth_m looks like millimetres: median 812; ...").
    """
    D = np.asarray(depth)
    step = max(1, int(math.sqrt(D.size / _MEDIAN_SAMPLES)))
    sample = D[::step, ::step] if D.ndim == 2 else D.ravel()[:: step * step]
    with np.errstate(invalid="ignore"):
        readings = sample[np.isfinite(sample) & (np.abs(sample) > MIN_VALID_DEPTH_M)]
    if readings.size == 0:
        return
    median = float(np.median(readings))
    lo, hi = DEPTH_MEDIAN_RANGE_M
    if lo <= median <= hi:
        return
    if median < 0.0:
        raise InvalidInputError(
            f"{name} is mostly negative (median {median:.4g}); depth along the optical axis is >= 0 m (mark "
            "pixels without a reading with 0 or NaN)"
        )
    if lo <= median / 1000.0 <= hi:
        raise InvalidInputError(
            f"{name} looks like millimetres: median {median:.0f}; pass metres "
            f"({name.removesuffix('_m')}_mm / 1000; RGB-D cameras measure {lo:g} - {hi:g} m)"
        )
    raise InvalidInputError(
        f"{name} median {median:.4g} m lies outside the {lo:g} - {hi:g} m that RGB-D cameras measure; "
        "pass depth in metres"
    )


def back_project(depth: ArrayLike, intrinsics: CameraIntrinsics, mask: ArrayLike | None = None) -> np.ndarray:
    """Camera-frame points of the valid depth pixels (optionally only those inside `mask`).

    Args:
        depth: (H, W) float depth along z [m]; 0, negative, NaN and inf mean "no reading" and are dropped.
        intrinsics: the camera; (height, width) must equal depth.shape.
        mask: optional (H, W) bool (or integer, nonzero = selected) pixel selection.
    Returns:
        (N, 3) float64 points [m], x = (u - cx) z / fx, y = (v - cy) z / fy, in row-major pixel order.
    """
    D = _depth(depth, intrinsics)
    keep = valid_depth_mask(D)
    if mask is not None:
        keep &= _pixel_mask(mask, D.shape)
    v, u = np.nonzero(keep)
    z = D[v, u].astype(np.float64)
    points = np.empty((len(z), 3))
    points[:, 0] = (u - intrinsics.cx) * z / intrinsics.fx
    points[:, 1] = (v - intrinsics.cy) * z / intrinsics.fy
    points[:, 2] = z
    return points


def masked_median_depth(depth: ArrayLike, mask: ArrayLike, radius_px: int) -> np.ndarray:
    """(H, W) float64 depth: each valid pixel of `mask` replaced by the median of the valid mask pixels in
    the (2 radius_px + 1)^2 window around it; every other pixel 0 (no reading).

    Only the mask's own readings enter a window, so a silhouette pixel is not averaged with the background;
    the median keeps a real step inside the object (a handle's edge) where a mean would smear it.
    """
    if isinstance(radius_px, bool) or not isinstance(radius_px, int) or radius_px < 0:
        raise InvalidInputError(f"radius_px must be an int >= 0, got {radius_px!r}")
    D = np.asarray(depth, dtype=np.float64)
    if D.ndim != 2:
        raise InvalidInputError(f"depth must be (H, W), got shape {D.shape}")
    keep = valid_depth_mask(D) & _pixel_mask(mask, D.shape)
    out = np.zeros_like(D)
    if not keep.any():
        return out
    rows, cols = np.nonzero(keep)
    r = radius_px
    v0, v1 = max(rows.min() - r, 0), min(rows.max() + r + 1, D.shape[0])
    u0, u1 = max(cols.min() - r, 0), min(cols.max() + r + 1, D.shape[1])
    crop = np.where(keep[v0:v1, u0:u1], D[v0:v1, u0:u1], np.nan)
    padded = np.pad(crop, r, constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (2 * r + 1, 2 * r + 1))
    sel = keep[v0:v1, u0:u1]
    out[v0:v1, u0:u1][sel] = np.nanmedian(windows[sel].reshape(int(sel.sum()), -1), axis=1)
    return out


#: 4-neighbours (row, column) of a pixel.
_NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0))


def outline_corrected_points(
    depth: ArrayLike, intrinsics: CameraIntrinsics, mask: ArrayLike, occlusion_margin_m: float
) -> np.ndarray:
    """An object's camera-frame points: `back_project` of its mask, the free outline moved half a pixel out.

    A depth pixel samples the surface at its centre, so the object's outermost pixels lie on average half a
    pixel inside its true outline, and the seen extent across the view is about one pixel short (a bottle
    6.5 cm wide 0.9 m away: 2 mm, 3 %). A point whose 4-neighbour off the mask is inside the image and not
    nearer than the point by more than `occlusion_margin_m` (background, or no reading) is on the object's
    own outline: it moves half a pixel towards each such neighbour, across its ray (x and y in proportion to
    its depth; z is kept). Edges the image border or an occluder (a nearer neighbour) cut are not the object's
    outline and stay. Every other point is exactly `back_project`'s.

    Masked pixels without a reading beside the outline (a sensor's edge dropout) are not walked over to
    where the mask ends: the grounder's masks take in such pixels beyond the object too, and doing so made
    widths 2-6 % too large on the development splits (docs/fit.md).

    Args:
        depth: (H, W) float depth [m], as `back_project`.
        intrinsics: the camera; (height, width) must equal depth.shape.
        mask: (H, W) bool (or integer, nonzero = selected): the object's pixels.
        occlusion_margin_m: a neighbour nearer than the point by more than this [m] is an occluder.
    Returns:
        (N, 3) float64 points [m], one per valid masked pixel, in `back_project`'s (row-major) order.
    """
    D = _depth(depth, intrinsics)
    M = _pixel_mask(mask, D.shape)
    if not (math.isfinite(occlusion_margin_m) and occlusion_margin_m >= 0.0):
        raise InvalidInputError(f"occlusion_margin_m must be a finite number >= 0, got {occlusion_margin_m}")
    valid = valid_depth_mask(D)
    v, u = np.nonzero(valid & M)
    z = D[v, u].astype(np.float64)
    du = np.zeros(len(z))
    dv = np.zeros(len(z))
    if len(z):
        # the few outline pixels first (a crop one pixel round the mask; off the image counts as on the
        # mask: the border cuts, it is not an outline), then their neighbours' depths
        H, W = D.shape
        r0, r1 = max(int(v[0]) - 1, 0), min(int(v[-1]) + 2, H)
        c0, c1 = max(int(u.min()) - 1, 0), min(int(u.max()) + 2, W)
        on = np.pad(M[r0:r1, c0:c1], 1, constant_values=True)
        inner = on[1:-1, 1:-1]
        edge = inner & ~(on[1:-1, 2:] & on[1:-1, :-2] & on[2:, 1:-1] & on[:-2, 1:-1])
        ev, eu = np.nonzero(edge & valid[r0:r1, c0:c1])
        ev += r0
        eu += c0
        k = np.searchsorted(v * W + u, ev * W + eu)  # their rows in the point list (row-major order)
        ez = z[k]
        for dr, dc in _NEIGHBOURS:
            nv, nu = ev + dr, eu + dc
            inside = (nv >= 0) & (nv < H) & (nu >= 0) & (nu < W)
            nv, nu = np.clip(nv, 0, H - 1), np.clip(nu, 0, W - 1)
            with np.errstate(invalid="ignore"):
                not_nearer = ~valid[nv, nu] | (D[nv, nu] >= ez - occlusion_margin_m)
            free = inside & ~M[nv, nu] & not_nearer
            du[k] += 0.5 * dc * free
            dv[k] += 0.5 * dr * free
    points = np.empty((len(z), 3))
    points[:, 0] = (u + du - intrinsics.cx) * z / intrinsics.fx
    points[:, 1] = (v + dv - intrinsics.cy) * z / intrinsics.fy
    points[:, 2] = z
    return points


def depth_to_point_map(depth: ArrayLike, intrinsics: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) float64 camera-frame point of every pixel [m]; NaN where the pixel has no depth reading."""
    D = _depth(depth, intrinsics)
    z = np.where(valid_depth_mask(D), D.astype(np.float64), np.nan)
    u = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
    v = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
    out = np.empty((*D.shape, 3))
    out[..., 0] = z * u[None, :]
    out[..., 1] = z * v[:, None]
    out[..., 2] = z
    return out


def as_points(points: ArrayLike, name: str = "points", min_points: int = 1) -> np.ndarray:
    """Validate a point cloud: (N, 3), finite, N >= `min_points`. Returns it as float64."""
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {P.shape}")
    if len(P) < min_points:
        have = "is empty" if len(P) == 0 else f"has {len(P)} points"
        raise InvalidInputError(f"{name} {have}; at least {min_points} are needed")
    if not np.all(np.isfinite(P)):
        raise InvalidInputError(f"{name} must be finite, got NaN or inf")
    return P


def farthest_point_sampling(points: ArrayLike, n: int, start_index: int = 0) -> np.ndarray:
    """Indices of `n` points chosen by farthest point sampling, starting from `start_index`.

    Each next point is the one farthest from all chosen so far (largest squared distance to its nearest
    chosen point). Deterministic and exact in float64; among exact ties the first along the sorting axis
    below wins. When n >= N every index is returned, in index order.

    Speed: numpy's fixed cost per call (~1.5 us) dominates a per-pick loop, so each pick does three calls.
    Points are sorted along their longest extent; a new centre c can only lower the nearest-distance of
    points closer to c than the current covering radius r (the distance of c itself, the largest of all),
    so only the slab |x - x_c| < r is updated, through one matrix product that yields
    |p|^2 - 2 p.c + |c|^2 for the slab. The slab shrinks as r does (typically to a few % of the points).

    Args:
        points: (N, 3) finite points [m].
        n: number of samples, >= 1.
        start_index: index of the first sample, in [0, N).
    Returns:
        (min(n, N),) intp indices into `points`, unique, first = start_index (when n < N).
    """
    P = as_points(points)
    N = len(P)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InvalidInputError(f"n must be a positive integer, got {n!r}")
    if isinstance(start_index, bool) or not isinstance(start_index, (int, np.integer)):
        raise InvalidInputError(f"start_index must be an integer, got {start_index!r}")
    if not 0 <= start_index < N:
        raise InvalidInputError(f"start_index must be in [0, {N}), got {start_index}")
    if n >= N:
        return np.arange(N, dtype=np.intp)
    # Centring keeps |p|^2 small, so the expanded distance loses no precision to cancellation.
    P = P - P.mean(axis=0)
    axis = int(np.argmax(np.ptp(P, axis=0)))
    order = np.argsort(P[:, axis], kind="stable")
    P = P[order]
    keys = np.ascontiguousarray(P[:, axis])
    norms_sq = np.einsum("ij,ij->i", P, P)
    # dist_sq(slab, c_j) = centre_terms[j] @ point_terms[:, slab], with
    # point_terms = (x, y, z, |p|^2, 1) and centre_terms[j] = (-2 c_j, 1, |c_j|^2).
    point_terms = np.vstack([P.T, norms_sq, np.ones(N)])
    centre_terms = np.column_stack([-2.0 * P, np.ones(N), norms_sq])
    nearest_sq = np.full(N, np.inf)
    chosen = np.empty(n, dtype=np.intp)
    j = int(np.flatnonzero(order == start_index)[0])
    chosen[0] = start_index
    lo, hi = 0, N
    for k in range(1, n):
        slab = nearest_sq[lo:hi]
        np.minimum(slab, centre_terms[j] @ point_terms[:, lo:hi], out=slab)
        j = int(nearest_sq.argmax())
        radius = math.sqrt(max(float(nearest_sq[j]), 0.0))
        lo = int(keys.searchsorted(keys[j] - radius, side="left"))
        hi = int(keys.searchsorted(keys[j] + radius, side="right"))
        chosen[k] = order[j]
    return chosen


@dataclass(frozen=True, eq=False)
class RobustDescriptor:
    """The paper's geometry descriptor d_t = c ⊕ vec(U) ⊕ e (section 3.5), from depth-clipped points.

    Attributes:
        centroid: (3,) float64 mean of the kept points, camera frame [m].
        axes: (3, 3) float64 principal directions as columns, by decreasing variance; right-handed.
        variances: (3,) float64 eigenvalues of the covariance [m^2], decreasing.
        extents: (3,) float64 side lengths [m] of the axis-aligned bounding box of the kept points, where
            "axis-aligned" means aligned with the camera axes x, y, z (as in the paper), not with `axes`.
        depth_range: (2,) float64 the [p_low, p_high] depth percentiles [m] used for clipping.
        num_points: how many points were kept.
    """

    centroid: np.ndarray
    axes: np.ndarray
    variances: np.ndarray
    extents: np.ndarray
    depth_range: np.ndarray
    num_points: int

    @property
    def vector(self) -> np.ndarray:
        """(15,) float64 c ⊕ vec(U) ⊕ e, with vec stacking the columns of U (column-major, as in maths)."""
        return np.concatenate([self.centroid, self.axes.ravel(order="F"), self.extents])


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


def robust_descriptor(
    points: ArrayLike, low_percentile: float = 5.0, high_percentile: float = 95.0
) -> RobustDescriptor:
    """Centroid, PCA axes and camera-axis-aligned extents of a camera-frame cloud after depth clipping.

    Steps (paper section 3.5): keep the points whose depth z lies in [p_low, p_high] (percentiles of z, linear
    interpolation, inclusive); c = mean; Sigma = (1/|P|) sum (x - c)(x - c)^T; U = eigenvectors of Sigma by
    decreasing eigenvalue; e = max - min of the kept points along the camera x, y, z axes.

    Sign convention for U (PCA fixes each axis only up to sign): the first two columns are flipped so that
    their entry of largest magnitude is positive (the first such entry on exact ties), and the third column is
    their cross product, so U is a rotation (right-handed).

    Args:
        points: (N, 3) finite camera-frame points [m], N >= 1.
        low_percentile, high_percentile: clipping percentiles in [0, 100], low < high.
    """
    P = as_points(points)
    lo_p, hi_p = float(low_percentile), float(high_percentile)
    if not (0.0 <= lo_p < hi_p <= 100.0):
        raise InvalidInputError(
            f"percentiles need 0 <= low < high <= 100, got low={low_percentile}, high={high_percentile}"
        )
    z_lo, z_hi = np.percentile(P[:, 2], [lo_p, hi_p])
    kept = P[(P[:, 2] >= z_lo) & (P[:, 2] <= z_hi)]
    centroid = kept.mean(axis=0)
    centred = kept - centroid
    cov = centred.T @ centred / len(kept)
    eigvals, eigvecs = np.linalg.eigh(cov)  # ascending
    order = np.argsort(eigvals, kind="stable")[::-1]
    variances, U = np.maximum(eigvals[order], 0.0), eigvecs[:, order]
    for col in (0, 1):
        if U[np.argmax(np.abs(U[:, col])), col] < 0.0:
            U[:, col] = -U[:, col]
    U[:, 2] = np.cross(U[:, 0], U[:, 1])
    extents = kept.max(axis=0) - kept.min(axis=0)
    return RobustDescriptor(
        centroid=_frozen(centroid),
        axes=_frozen(U),
        variances=_frozen(variances),
        extents=_frozen(extents),
        depth_range=_frozen(np.array([z_lo, z_hi])),
        num_points=len(kept),
    )
