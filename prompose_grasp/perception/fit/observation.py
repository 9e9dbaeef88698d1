"""What the camera saw of the object: the observed points the fit runs on, and where the camera could see.

- `observed_points`: the depth gate (mask bleed onto far background goes) and the subsample the fit runs on
  (2048 points, paper section 4.1), its first few hundred reordered by farthest point sampling for the
  coarse stages;
- `SceneView` and the visibility tests built on it: a posed prior point the camera could have seen
  (`_observable`), observed points on the image border or an occluder's edge (`_on_border`,
  `_next_to_occluder`), and the camera-facing share of a fitted shape the mask shows (`mask_coverage`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.occlusion import nearer_beside
from prompose_grasp.geometry.pointcloud import farthest_point_sampling
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.prior import ShapePrior

__all__ = ["SceneView", "mask_coverage", "observed_points", "visible_prior_mask"]

#: An observed point whose pixel lies within this many pixels of the image border shows where the image cuts
#: the object off (`_cut_sides`).
_BORDER_PX = 2.0
#: An observed point with a pixel off the object's mask within this many pixels that reads nearer (by the
#: occlusion margin) lies on an occluder's edge (`_next_to_occluder`): the grid of a segmentation mask is
#: 2-4 px, so a mask edge and the occluder's first readings can be that far apart.
_OCCLUDER_PX = 3
#: The image border or an occluder cuts off a side of the box when at least this share of the points at that


@dataclass(frozen=True, eq=False)
class SceneView:
    """The depth image the observed points were back-projected from, and the object's pixels in it.

    With it the fit knows where the camera could have seen the object: a prior point that projects outside
    the image, or off the object's mask onto a pixel without a depth reading or behind a nearer surface (an
    occluder), is not expected in the observation (`FitConfig.scene_occlusion`). A point on the mask is
    expected even where the sensor gave no reading (docs/fit.md: leaving those out was measured, no gain).

    Attributes:
        depth_m: (H, W) float depth image [m] (0 or non-finite = no reading), the camera of `points_cam`.
        intrinsics: its pinhole intrinsics (`intrinsics.shape == depth_m.shape`).
        mask: (H, W) bool, the object's pixels (the mask the points came from).
    """

    depth_m: np.ndarray
    intrinsics: CameraIntrinsics
    mask: np.ndarray

    def __post_init__(self) -> None:
        if not isinstance(self.intrinsics, CameraIntrinsics):
            raise InvalidInputError(
                f"SceneView.intrinsics must be a CameraIntrinsics, got {type(self.intrinsics).__name__}"
            )
        d = np.asarray(self.depth_m)
        m = np.asarray(self.mask)
        if d.shape != self.intrinsics.shape or not np.issubdtype(d.dtype, np.floating):
            raise InvalidInputError(
                f"SceneView.depth_m must be a float {self.intrinsics.shape} (height, width) image in metres, "
                f"got {d.dtype} {d.shape}"
            )
        if m.shape != d.shape or m.dtype != np.bool_:
            raise InvalidInputError(f"SceneView.mask must be a bool {d.shape} image, got {m.dtype} {m.shape}")
        object.__setattr__(self, "depth_m", d)
        object.__setattr__(self, "mask", m)


def _observable(scene: SceneView, x: np.ndarray, margin: float) -> np.ndarray:
    """(M,) bool: posed prior points `x` (M, 3) the camera could have seen, given the scene: inside the
    image, on the object's mask, or on a pixel with a depth reading not nearer than the point by more than
    `margin` (nothing else in front of it)."""
    ok, iu, iv = _pixels(scene.intrinsics, x)
    out = np.zeros(len(x), dtype=bool)
    d = scene.depth_m[iv, iu]
    on_mask = scene.mask[iv, iu]
    with np.errstate(invalid="ignore"):
        free = (d > 0.0) & (d >= x[ok, 2] - margin)  # NaN (no reading) compares False
    out[ok] = on_mask | free
    return out


def _pixels(intr: CameraIntrinsics, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame points `x` (M, 3) -> (M,) bool in front of the camera and inside the image, and the
    column and row index of the pixel of each of those (nearest pixel centre)."""
    z = x[:, 2]
    ok = z > 1e-6
    zs = np.where(ok, z, 1.0)
    u = np.floor(intr.fx * x[:, 0] / zs + intr.cx + 0.5)
    v = np.floor(intr.fy * x[:, 1] / zs + intr.cy + 0.5)
    ok &= (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
    return ok, u[ok].astype(np.intp), v[ok].astype(np.intp)


# --------------------------------------------------------------------------------------------------------
# Input checks


def visible_prior_mask(pose: Pose9D, normals_unit: ArrayLike, points_unit: ArrayLike) -> np.ndarray:
    """(M,) bool: prior points whose outward normal faces the camera once posed by `pose`.

    A normal n of the unit-box surface becomes R diag(1/size) n in the camera frame (normals transform by the
    inverse transpose of the linear map R diag(size)); a point p_cam faces the camera (at the origin) when
    n_cam . p_cam < 0. Self-occlusion by other parts of a non-convex shape is not modelled.
    """
    Pn = np.asarray(normals_unit, dtype=np.float64)
    P = np.asarray(points_unit, dtype=np.float64)
    n_cam = (Pn / pose.size) @ pose.R.T
    p_cam = (P * pose.size) @ pose.R.T + pose.t
    return np.einsum("ij,ij->i", n_cam, p_cam) < 0.0


def mask_coverage(pose: Pose9D, prior: ShapePrior, scene: SceneView) -> float:
    """Fraction of the fitted shape's camera-facing surface that the object's mask shows, in [0, 1].

    The prior's surface points are posed by `pose`; of those facing the camera (`visible_prior_mask`), the
    fraction projecting inside the image onto `scene.mask`. Near 1 when the whole side the camera faces is
    seen. Lower when part of it falls outside the image or behind an occluder, where the amodal box rests on
    the prior alone, or when the box is larger than the points support: a confidence in the fit, measured
    (docs/fit.md) to rank right and wrong boxes apart. NaN when no prior point faces the camera.
    """
    P = np.asarray(prior.points, dtype=np.float64)
    x = pose.points_to_camera(P[visible_prior_mask(pose, prior.normals, P)])
    x = x[x[:, 2] > 1e-6]
    if len(x) == 0:
        return math.nan
    _, iu, iv = _pixels(scene.intrinsics, x)
    return float(np.count_nonzero(scene.mask[iv, iu])) / len(x)


def _on_border(intr: CameraIntrinsics, pts: np.ndarray) -> np.ndarray:
    """(N,) bool: points `pts` (N, 3) whose pixel lies within `_BORDER_PX` of the image border."""
    u, v = intr.project(pts).T
    b = _BORDER_PX
    return (u <= b) | (u >= intr.width - 1 - b) | (v <= b) | (v >= intr.height - 1 - b)


def _next_to_occluder(scene: SceneView, pts: np.ndarray, margin: float) -> np.ndarray:
    """(N,) bool: observed points `pts` (N, 3) with a pixel off the object's mask within `_OCCLUDER_PX` of
    theirs whose depth reading is nearer than the point by more than `margin`: the object's silhouette there
    is an occluder's edge, not the object's end (`geometry.occlusion.nearer_beside`)."""
    ok, u, v = _pixels(scene.intrinsics, pts)
    out = np.zeros(len(pts), dtype=bool)
    out[ok] = nearer_beside(scene.depth_m, scene.mask, v, u, pts[ok, 2], _OCCLUDER_PX, margin)
    return out


@dataclass(frozen=True)
class _Cuts:
    """Where the object's silhouette is not its own end (`_cut_edges`).

    Attributes:
        edge: (N,) bool per gated point: on the image border or an occluder's edge; None: not looked for.
        by_image: some point lies on the image border.
        by_occluder: some point lies on an occluder's edge.
    """

    edge: np.ndarray | None = None
    by_image: bool = False
    by_occluder: bool = False


def _cut_edges(view: SceneView | None, pts: np.ndarray, margin: float) -> _Cuts:
    """Observed points `pts` (N, 3) where the image border (`_on_border`) or an occluder
    (`_next_to_occluder`, depth nearer by more than `margin` [m]) cuts the object off; none without a view."""
    if view is None:
        return _Cuts()
    on_border = _on_border(view.intrinsics, pts)
    by_occluder = _next_to_occluder(view, pts, margin)
    return _Cuts(on_border | by_occluder, bool(np.any(on_border)), bool(np.any(by_occluder)))


# --------------------------------------------------------------------------------------------------------
# The observed points


def observed_points(pts_all: np.ndarray, cfg: FitConfig, warm: bool) -> tuple[np.ndarray, np.ndarray]:
    """The object's points after the depth gate (N', 3), and the subsample the fit runs on (n, 3).

    The gate keeps depths within [p5 - g, p95 + g], g = `depth_gate_ratio` (p95 - p5) + 1 cm. A cold
    start keeps `n_points` by `cfg.subsample`, its first points (as many as the largest coarse stage uses)
    reordered by farthest point sampling; a warm start a seeded random `n_points_warm`.
    """
    z = pts_all[:, 2]
    # percentiles of an even stride of at most ~8k points: as good for a gate, and O(N) work stays small
    z_lo, z_hi = np.percentile(z[:: max(1, len(z) // 8192)], cfg.clip_percentiles)
    gate = cfg.depth_gate_ratio * (z_hi - z_lo) + 0.01
    pts = pts_all[(z >= z_lo - gate) & (z <= z_hi + gate)]
    if len(pts) < cfg.min_points:
        raise InvalidInputError(
            f"only {len(pts)} points are left after the depth gate; the fit needs {cfg.min_points}"
        )
    n_obs = cfg.n_points_warm if warm else cfg.n_points
    obs = _subsample(pts, n_obs, "random" if warm else cfg.subsample, cfg.seed)
    n_coarse = max((st.obs_points for st in cfg.stages[:-1]), default=0)
    if not warm and cfg.subsample == "voxel" and 0 < n_coarse < len(obs):
        # the coarse stages rank the hypotheses on a prefix: make it an even farthest-point cover (a random
        # prefix is clumpy and misses thin parts such as a mug's handle); FPS of a few hundred points
        # out of the voxel sample costs a few ms
        start = int(np.argmin(np.sum((obs - obs.mean(axis=0)) ** 2, axis=1)))
        head = farthest_point_sampling(obs, n_coarse, start_index=start)
        rest = np.ones(len(obs), dtype=bool)
        rest[head] = False
        obs = np.concatenate([obs[head], obs[rest]])
    return pts, obs


def _subsample(pts: np.ndarray, n: int, how: str, seed: int) -> np.ndarray:
    """At most n of the points, in an order whose every prefix is a coarser sample of the same surface.

    "voxel": one random point per voxel of a grid sized to leave about n occupied voxels (even density over
    the surface however the camera's sampling varies with depth and slant, like farthest point sampling at a
    fraction of its cost), in random order. "random": a seeded random subset in random order. "fps":
    farthest point sampling (FPS order). Fewer than n points: all of them, in random order (raster order
    would make a prefix the top rows of the object).
    """
    rng = np.random.default_rng(seed)
    if len(pts) <= n:
        return pts[rng.permutation(len(pts))]
    if how == "fps":
        # start at the point nearest the centroid: deterministic and inside the cloud
        start = int(np.argmin(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1)))
        return pts[farthest_point_sampling(pts, n, start_index=start)]
    if how == "voxel":
        shuffled = pts[rng.permutation(len(pts))]
        lo = shuffled.min(axis=0)
        span = float(np.max(shuffled.max(axis=0) - lo))
        # a surface patch of extent L holds ~(L / v)^2 voxels: start there, then correct by the count seen
        v = max(span / math.sqrt(n), 1e-4)
        keep = np.arange(len(shuffled))
        for _ in range(3):
            keys = np.floor((shuffled - lo) / v).astype(np.int64)
            _, first = np.unique(keys[:, 0] * 4194304 * 4194304 + keys[:, 1] * 4194304 + keys[:, 2],
                                 return_index=True)  # fmt: skip
            keep = first
            ratio = len(first) / n
            if 1.0 <= ratio <= 1.3:
                break
            v *= math.sqrt(ratio) if ratio > 0 else 0.5
        keep = np.sort(keep)  # shuffled order: a random representative per voxel, in random order
        return shuffled[keep[:n]] if len(keep) >= n else shuffled[keep]
    idx = rng.choice(len(pts), size=n, replace=False)
    return pts[idx]
