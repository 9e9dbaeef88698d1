"""Metric 9-DoF fit of a canonical shape prior to the observed points: a test-time minimisation of L_geo.

The paper (section 3.7) trains its network with L_geo, the bidirectional squared Chamfer distance between the
scaled, posed prior `R diag(s) P_prior + T` and the masked observation. Here L_geo is minimised directly for
one frame, over the rotation, the translation and the anisotropic size, from several initial hypotheses.

Pipeline of `fit_pose` (docs/fit.md has the reasons for each choice):

1. Observation: a depth gate around the [p5, p95] depth range (mask bleed onto far background goes), a voxel
   subsample to `n_points` (2048, paper section 4.1: one random point per voxel, so density is even over the
   surface) whose first few hundred points are reordered by farthest point sampling (the coarse stages run
   on that prefix), a random subsample on warm starts, and the paper's robust descriptor (centroid, PCA
   axes, extents after [p5, p95] depth clipping, section 3.5).
2. Hypotheses: with a support-plane normal `up_cam`, the object's +y is up and only the yaw is unknown:
   yaws spaced evenly from the principal direction of the points projected on the plane (8 for asymmetric
   shapes, 4 for two-fold ones, 1 for shapes round about y, tried at three section widths); without it,
   the 24 proper rotations that map the object axes onto the signed, permuted PCA axes (6 when only the y
   axis matters). An articulated family (a laptop: `priors.library.articulated_variants`) adds its other
   articulations at the best coarse yaw. A warm start `init` is the single hypothesis.
3. Amodal initial box: extents of the points in the hypothesis frame are lower bounds (one side is seen);
   the prior's metric aspect ratios fill the unseen depth, the box grows away from the camera, and with a
   support plane the bottom face sits on the plane.
4. Minimisation of the visibility-aware, robust L_geo: ICP-style alternation of nearest neighbours (cKDTree)
   and a damped Gauss-Newton step on point-to-point residuals with Huber weights, the normal equations
   summed in closed form from 3x3 moments. Prior points pull on the observation (prior -> observation
   term) only when their normal faces the camera and a coarse z-buffer of the posed prior does not hide
   them behind its own nearer surface; every prior point can be the nearest neighbour of an observed point
   (observation -> prior term). A weak prior on the log-aspect ratios keeps sizes along unseen directions
   at the prior's proportions. All hypotheses run a short coarse stage on subsampled clouds (the worse half
   dropped halfway); the best few are refined on the full clouds; the lowest loss wins.
5. Symmetry-aware output: for shapes round about y the yaw is canonical (object +z towards the camera),
   likewise for the other symmetry tags, so equal shapes give equal poses.
"""

from __future__ import annotations

import logging
import math
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.occlusion import cut_ends, nearer_beside
from prompose_grasp.geometry.pointcloud import (
    back_project,
    farthest_point_sampling,
    masked_median_depth,
    robust_descriptor,
)
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import project_to_so3, so3_exp
from prompose_grasp.perception.priors.library import (
    articulated_variants,
    aspect_weight_factors,
    round_body_axis,
)
from prompose_grasp.perception.priors.prior import SYMMETRIES, ShapePrior

__all__ = [
    "FitConfig",
    "FitResult",
    "FitStage",
    "SceneView",
    "canonicalize_symmetry",
    "fit_pose",
    "grow_to_seen",
    "mask_coverage",
    "protrusion_points",
    "seen_surface",
    "visible_prior_mask",
]

log = logging.getLogger(__name__)

#: Number of yaw hypotheses about the support normal, per symmetry tag (see `_yaw_count`).
_YAWS = {"none": 8, "box": 4, "y_2fold": 8, "x_continuous": 4, "y_continuous": 1, "spherical": 1}

#: Width factors of the initial section of round shapes (one hypothesis each, see `fit_pose`).
_ROUND_WIDTHS = (1.0, 1.15, 1.3)

#: An observed point whose pixel lies within this many pixels of the image border shows where the image cuts
#: the object off (`_cut_sides`).
_BORDER_PX = 2.0
#: An observed point with a pixel off the object's mask within this many pixels that reads nearer (by the
#: occlusion margin) lies on an occluder's edge (`_next_to_occluder`): the grid of a segmentation mask is
#: 2-4 px, so a mask edge and the occluder's first readings can be that far apart.
_OCCLUDER_PX = 3
#: The image border or an occluder cuts off a side of the box when at least this share of the points at that
#: end of the box axis (its outer 2 %, beyond the percentiles of the seen extents) lie on such a cut edge
#: (`_cut_sides`): where the cut crosses the object's end, the farthest points along the axis are the cut's;
#: at a free end they are the object's own silhouette.
_CUT_SHARE = 0.5

#: Sizes are kept in [1 mm, 20 m]: outside that range a fit has diverged, whatever the object.
_LOG_SIZE_MIN, _LOG_SIZE_MAX = math.log(1e-3), math.log(20.0)


@dataclass(frozen=True)
class FitStage:
    """One stage of the coarse-to-fine schedule: cloud sizes, Gauss-Newton iterations, survivors."""

    obs_points: int
    prior_points: int
    iterations: int
    keep: int

    def __post_init__(self) -> None:
        for name in ("obs_points", "prior_points", "keep"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidInputError(f"FitStage.{name} must be a positive int, got {v!r}")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 0:
            raise InvalidInputError(f"FitStage.iterations must be an int >= 0, got {self.iterations!r}")


@dataclass(frozen=True)
class FitConfig:
    """Settings of `fit_pose`. Lengths in metres.

    Attributes:
        n_points: observed points kept on a cold start (paper: 2048), by `subsample`.
        n_points_warm: observed points kept on a warm start (a seeded random subsample: a tracking frame
            has ~15 ms for the whole fit).
        n_prior_points: prior points used (a farthest-point subset of the prior's 5000, cached per prior).
        clip_percentiles: depth percentiles of the paper's robust descriptor (section 3.5).
        depth_gate_ratio: points with depth outside [p5 - g, p95 + g], g = ratio * (p95 - p5) + 1 cm, are
            dropped before the fit (mask bleed onto the background far behind or in front of the object). The
            [p5, p95] clip itself would cut the true nearest and farthest 5 % of the surface.
        min_points: fewer valid observed points than this is an error.
        huber_m: Huber threshold on point distances [m]: beyond it a residual pulls with constant force
            (mask bleed, occluders, depth noise tails). ~3 sigma of RealSense noise at 1 m.
        visible_cos: a prior point pulls on the observation (prior -> observation term) when the cosine
            between its posed normal and the direction to the camera exceeds this. Above 0 because depth
            sensors return nothing at grazing angles (edge dropout), so near-silhouette prior points would
            pull the box smaller.
        aspect_weight: weight of the log-aspect prior [m per unit log-ratio]; small, so that it decides only
            sizes the observation leaves free (the unseen depth). A library family whose function ties a
            pair of extents multiplies it for that pair (`ShapeFamily.aspect_weight_factors`: a laptop's
            screen height and base depth, 10x).
        stages: coarse-to-fine schedule of a cold start: every hypothesis runs the first stage; after each
            stage the `keep` lowest-loss ones go on to the next, finer one.
        warm_prior_points, warm_iterations: prior points and iterations of a warm start.
        step_tol: stop when the update's rotation [rad] and translation / log-size steps fall below this.
        damping: Levenberg-Marquardt damping relative to the mean diagonal of the normal matrix.
        seed: seed of the random subsample on warm starts (the fit is deterministic).
        subsample: how the cold start picks its `n_points`: "voxel" (one random point per voxel, random
            order) or "fps" (farthest point sampling, the paper's choice; 20-60 ms of one core for 2048).
        articulations: try the prior's articulated variants (`priors.library.articulated_variants`, e.g. a
            laptop's screen at other openings) on cold starts.
        self_occlusion: prior points hidden behind the prior's own nearer surface do not pull (a coarse
            z-buffer of the posed prior, `_not_self_occluded`).
        contain_weight: weight of the containment term: an observed point outside the amodal box by more
            than `contain_margin_m` pays its squared (Huber) excess, averaged over the observed points like
            a Chamfer term. The seen surface lies inside the true box, so its extents are lower bounds on
            the box; the Chamfer terms alone let a prior whose proportions differ from the instance's (a
            bottle's shoulder higher than this one's) trade the seen extent for a better shape match (the
            bottles' radius came out ~8 % small). A body of revolution (symmetry "y_continuous") holds its
            points in the cylinder inscribed in the box: the box's corners would let a round section ~6 %
            narrower than the seen one contain it (docs/fit.md). 0 turns it off.
        contain_margin_m: excess tolerated before the containment term pulls [m]: about one standard
            deviation of the depth noise of a RealSense at ~1 m, so the noise does not inflate the box.
        contain_cap_m: a point outside the box by more than this (beyond the margin) is an outlier of the
            mask (table or neighbour pixels a grounded mask took in) and does not pull: its cost is held at
            the cap's [m]. The seen extent a prior mismatch hides is millimetres (a bottle's radius 8 % of
            ~3.5 cm). On the first 24 frames of the seed-21 test split, exact 3D50 / 3D75 with grounded
            masks: no containment 93.1 / 68.6, uncapped 82.7 / 46.4, cap 10 mm 92.3 / 58.2, cap 4 mm 93.1 /
            77.5; with oracle masks 93.8 / 65.0, 98.7 / 86.5, 98.7 / 86.5, 97.3 / 87.7 (docs/fit.md).
        scene_occlusion: with a `SceneView` (the depth image the points came from), a prior point the camera
            could not have seen does not pull on the observation: it projects outside the image, or off the
            object's mask onto a pixel without a depth reading or behind a nearer surface (an occluder in
            front, by more than `occlusion_margin_m`). Without it a mug behind a bottle or cut by the
            image border shrank to its visible fragment (docs/fit.md).
        occlusion_stages: the scene view is used in this many of the last stages of a cold start (and on
            warm starts); the coarse stages rank the hypotheses without it. With it in all four stages the
            coarse ranking dropped the right yaw of a few more mugs on the dev splits (docs/fit.md). An
            object an occluder cuts off (`_next_to_occluder`) has it in every stage.
        handle_band_tol, handle_band_min, handle_scan_step_deg, handle_margin_m, handle_min_points: a prior
            with a round body and a protrusion (`priors.library.round_body_axis`: a mug and its handle).
            When fewer than `handle_min_points` observed points lie outside the fitted body by more than
            `handle_margin_m` (the handle is not seen; the NOCS protocol uses 20 pixels), the loss is
            evaluated at turns of the handle about the body's axis every `handle_scan_step_deg`; the turns
            within `handle_band_tol` (relative) of the least are the ones that keep the handle out of sight,
            and when they span at least `handle_band_min` steps the handle goes to their middle (straight
            behind the body unless an occluder or the image border hides other turns too). The ground-truth
            box includes the handle, so its centre swings with that turn; the middle is the least worst
            guess. Negative `handle_band_tol` turns it off.
        handle_sliver_points, handle_match_m, handle_match_step_deg, handle_yaw_range_deg: the handle's own
            points (at least `handle_sliver_points` outside the body) set its yaw: turns about the body's
            axis all round the circle, every `handle_match_step_deg` and then to 1 deg, and the one whose
            visible handle points (the prior's, facing the camera) lie closest to them wins (mean squared
            distance, each capped at 1 cm). The fit's optimum can sit a quarter turn off a seen handle, and
            a handle seen edge-on shows fewer than `handle_min_points`; those few (a sliver, or stray edge
            points of a hidden handle) count only when their RMS distance is at most `handle_match_m` [m]
            (dev splits: seen slivers 2.9-7.6 mm, stray points 8.2-9.8 mm). The turn is taken when the loss
            stays within `handle_band_tol` of the fit's; else a seen handle is searched within
            +-`handle_yaw_range_deg` only (the full fit leaves seen handles 3-8 deg off: the body and the
            handle share the x scale, and the family's handle differs from the instance's). A
            `handle_yaw_range_deg` of 0 turns the handle's own yaw off.
        grow_min_points, grow_margin_m, grow_median_px, grow_density_radius_m, grow_density_min,
        grow_density_spacings, grow_plane_clearance_m: after the fit, each face of the box moves out to the
            seen surface beyond it (`grow_to_seen`, with a `SceneView` only): the observed extents are lower
            bounds the capped containment term lets a mismatched prior leave out (a hammer's head on a
            superquadric). A face moves when `grow_min_points` surface points lie beyond it by more than
            `grow_margin_m`, to the `grow_min_points`-th farthest less the margin. The surface: the mask's
            median depth over (2 `grow_median_px` + 1)^2 pixels (its noise a fifth of a pixel's at 2 px),
            points more than `grow_plane_clearance_m` above the support (about one sigma of the depth noise
            at 1 m: the table pixels a mask took in stay out), with more than `grow_density_min` neighbours
            within the link radius (`grow_density_radius_m`, or `grow_density_spacings` point spacings on a
            sparsely sampled far object) and connected through such points to the fitted box's inside.
        occlusion_margin_m: a pixel outside the object's mask occludes a prior point when its depth is
            nearer than the point's by more than this [m]: several sigma of the depth noise, and less than
            the gap between an occluder's front and the object behind it (objects do not interpenetrate).
    """

    n_points: int = 2048
    n_points_warm: int = 384
    n_prior_points: int = 1536
    clip_percentiles: tuple[float, float] = (5.0, 95.0)
    depth_gate_ratio: float = 0.5
    min_points: int = 30
    huber_m: float = 0.01
    visible_cos: float = 0.35
    aspect_weight: float = 0.003
    stages: tuple[FitStage, ...] = (
        FitStage(obs_points=256, prior_points=384, iterations=4, keep=4),
        FitStage(obs_points=256, prior_points=384, iterations=4, keep=3),
        FitStage(obs_points=768, prior_points=768, iterations=8, keep=1),
        FitStage(obs_points=2048, prior_points=1536, iterations=15, keep=1),
    )
    warm_prior_points: int = 512
    warm_iterations: int = 12
    step_tol: float = 1e-4
    damping: float = 1e-6
    seed: int = 0
    subsample: str = "voxel"
    articulations: bool = True
    self_occlusion: bool = True
    contain_weight: float = 30.0
    contain_margin_m: float = 0.001
    contain_cap_m: float = 0.004
    contain_ray_margin_m: float = 0.003
    scene_occlusion: bool = True
    occlusion_margin_m: float = 0.01
    occlusion_stages: int = 2
    handle_band_tol: float = 0.4
    handle_band_min: int = 3
    handle_scan_step_deg: float = 20.0
    handle_margin_m: float = 0.006
    handle_min_points: int = 20
    handle_yaw_range_deg: float = 12.0
    handle_sliver_points: int = 8
    handle_match_m: float = 0.008
    handle_match_step_deg: float = 5.0
    grow_min_points: int = 5
    grow_median_px: int = 2
    grow_margin_m: float = 0.003
    grow_density_radius_m: float = 0.006
    grow_density_min: int = 4
    grow_density_spacings: float = 3.0
    grow_plane_clearance_m: float = 0.004

    def __post_init__(self) -> None:
        ints = {
            "n_points": self.n_points,
            "n_points_warm": self.n_points_warm,
            "n_prior_points": self.n_prior_points,
            "min_points": self.min_points,
            "warm_prior_points": self.warm_prior_points,
            "handle_band_min": self.handle_band_min,
            "handle_min_points": self.handle_min_points,
            "handle_sliver_points": self.handle_sliver_points,
            "occlusion_stages": self.occlusion_stages,
            "grow_density_min": self.grow_density_min,
        }
        for name, v in ints.items():
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidInputError(f"FitConfig.{name} must be a positive int, got {v!r}")
        for name in ("warm_iterations", "grow_min_points", "grow_median_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise InvalidInputError(f"FitConfig.{name} must be an int >= 0, got {v!r}")
        if not self.stages or not all(isinstance(st, FitStage) for st in self.stages):
            raise InvalidInputError("FitConfig.stages must be a non-empty tuple of FitStage")
        if self.min_points < 4:
            raise InvalidInputError(
                f"FitConfig.min_points must be >= 4 (a box has 9 DoF), got {self.min_points}"
            )
        if self.subsample not in ("voxel", "fps"):
            raise InvalidInputError(f"FitConfig.subsample must be 'voxel' or 'fps', got {self.subsample!r}")
        lo, hi = self.clip_percentiles
        if not 0.0 <= lo < hi <= 100.0:
            raise InvalidInputError(f"FitConfig.clip_percentiles needs 0 <= low < high <= 100, got {lo, hi}")
        floats: dict[str, float] = {
            "depth_gate_ratio": self.depth_gate_ratio,
            "huber_m": self.huber_m,
            "visible_cos": self.visible_cos,
            "aspect_weight": self.aspect_weight,
            "step_tol": self.step_tol,
            "damping": self.damping,
            "contain_weight": self.contain_weight,
            "contain_margin_m": self.contain_margin_m,
            "contain_cap_m": self.contain_cap_m,
            "contain_ray_margin_m": self.contain_ray_margin_m,
            "occlusion_margin_m": self.occlusion_margin_m,
            "handle_margin_m": self.handle_margin_m,
            "handle_yaw_range_deg": self.handle_yaw_range_deg,
            "handle_match_m": self.handle_match_m,
            "grow_margin_m": self.grow_margin_m,
            "grow_density_radius_m": self.grow_density_radius_m,
            "grow_density_spacings": self.grow_density_spacings,
            "grow_plane_clearance_m": self.grow_plane_clearance_m,
        }
        for name, fv in floats.items():
            if not (isinstance(fv, int | float) and math.isfinite(fv) and fv >= 0.0):
                raise InvalidInputError(f"FitConfig.{name} must be a finite number >= 0, got {fv!r}")
        if not (isinstance(self.handle_band_tol, int | float) and math.isfinite(self.handle_band_tol)):
            raise InvalidInputError(
                f"FitConfig.handle_band_tol must be a finite number, got {self.handle_band_tol!r}"
            )
        if not 0.0 < self.handle_match_step_deg <= 30.0:
            raise InvalidInputError(
                f"FitConfig.handle_match_step_deg must be in (0, 30], got {self.handle_match_step_deg}"
            )
        if not 0.0 < self.handle_scan_step_deg <= 120.0:
            raise InvalidInputError(
                f"FitConfig.handle_scan_step_deg must be in (0, 120], got {self.handle_scan_step_deg}"
            )
        if self.huber_m <= 0.0:
            raise InvalidInputError(f"FitConfig.huber_m must be > 0 metres, got {self.huber_m}")


@dataclass(frozen=True)
class FitResult:
    """Outcome of `fit_pose`.

    Attributes:
        pose: the fitted amodal box, camera frame, symmetry-canonical (see `canonicalize_symmetry`).
        loss: L_geo of the result [m^2]: `obs_to_prior + prior_to_obs` (squared distances, no robust
            weighting, visible prior points only in the second term), on the points the fit used.
        obs_to_prior: mean over observed points of the squared distance to the nearest prior point [m^2].
        prior_to_obs: mean over visible prior points of the squared distance to the nearest observed point.
        robust_loss: the Huber-weighted objective the hypotheses were ranked by [m^2].
        hypotheses: number of initial hypotheses tried.
        hypothesis_losses: final robust loss of each refined hypothesis, in the order tried [m^2].
        iterations: Gauss-Newton iterations over all stages and hypotheses.
        n_points: observed points the fit used.
        mode: "upright_plane" (support plane given), "upright" (up only), "free", or "warm_*" variants.
        time_s: wall time of the call [s].
        prior: the prior whose shape won: the one passed in, or one of its articulated variants
            (`priors.library.articulated_variants`: a laptop's screen at another opening); pass it to the
            next warm-started call.
        coverage: `mask_coverage` of the result in the scene passed to `fit_pose`, in [0, 1]; NaN without
            a scene.
        surface_points: (M, 3) the object's seen surface in the camera frame [m] (`seen_surface`: the
            points the box was grown to), or None without a scene.
    """

    pose: Pose9D
    loss: float
    obs_to_prior: float
    prior_to_obs: float
    robust_loss: float
    hypotheses: int
    hypothesis_losses: tuple[float, ...]
    iterations: int
    n_points: int
    mode: str
    time_s: float
    prior: ShapePrior | None = None
    coverage: float = math.nan
    surface_points: np.ndarray | None = None


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


def _check_points(points_cam: ArrayLike, min_points: int) -> np.ndarray:
    P = np.asarray(points_cam)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points_cam must have shape (N, 3) in metres, got {P.shape}")
    if not np.issubdtype(P.dtype, np.number) or np.issubdtype(P.dtype, np.complexfloating):
        raise InvalidInputError(f"points_cam must be real numbers (metres), got dtype {P.dtype}")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InvalidInputError(
            "points_cam holds NaN or inf; drop pixels without a depth reading first (back_project does)"
        )
    if len(P) < min_points:
        raise InvalidInputError(
            f"points_cam has {len(P)} points; the fit needs at least {min_points} (FitConfig.min_points)"
        )
    if np.any(P[:, 2] <= 0.0):
        raise InvalidInputError("points_cam must lie in front of the camera (z > 0, OpenCV camera frame)")
    return P


def _check_unit(v: ArrayLike | None, name: str) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} must be a finite (3,) direction in the camera frame, got {v!r}")
    n = float(np.linalg.norm(a))
    if n < 1e-9:
        raise InvalidInputError(f"{name} must be a non-zero direction, got {v!r}")
    return a / n


def _check_plane(plane: ArrayLike | None, up: np.ndarray | None) -> tuple[np.ndarray, float] | None:
    if plane is None:
        return None
    a = np.asarray(plane, dtype=np.float64)
    if a.shape != (4,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(
            f"support_plane_cam must be a finite (4,) plane (nx, ny, nz, d) with n.x + d = 0, got {plane!r}"
        )
    n = float(np.linalg.norm(a[:3]))
    if n < 1e-9:
        raise InvalidInputError("support_plane_cam has a zero normal")
    normal, d = a[:3] / n, float(a[3]) / n
    if up is not None and float(normal @ up) < math.cos(math.radians(5.0)):
        raise InvalidInputError(
            "up_cam and the normal of support_plane_cam disagree by more than 5 degrees; pass one of them "
            "or make them agree (the plane normal must point up, towards the object)"
        )
    return normal, d


# --------------------------------------------------------------------------------------------------------
# Prior subsets (cached per prior object)

#: Farthest-point order of each prior's points (first 2048), kept while the prior lives.
_PRIOR_ORDER: weakref.WeakKeyDictionary[ShapePrior, np.ndarray] = weakref.WeakKeyDictionary()


def _prior_subset(prior: ShapePrior, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) unit-box points and (n, 3) normals: the first n farthest-point samples of the prior, so that a
    smaller subset is a coarser version of a larger one."""
    order = _PRIOR_ORDER.get(prior)
    if order is None:
        pts = np.asarray(prior.points, dtype=np.float64)
        order = farthest_point_sampling(pts, min(len(pts), 2048))
        _PRIOR_ORDER[prior] = order
    idx = order[: min(n, len(order))]
    return (
        np.asarray(prior.points, dtype=np.float64)[idx],
        np.asarray(prior.normals, dtype=np.float64)[idx],
    )


def _check_prior(prior: ShapePrior) -> None:
    if not isinstance(prior, ShapePrior):
        raise InvalidInputError(f"prior must be a ShapePrior, got {type(prior).__name__}")
    if prior.symmetry not in SYMMETRIES:
        raise InvalidInputError(f"prior.symmetry {prior.symmetry!r} is not one of {SYMMETRIES}")
    if len(prior.points) < 4 or prior.points.shape != prior.normals.shape:
        raise InvalidInputError("prior needs >= 4 points with one normal each")


# --------------------------------------------------------------------------------------------------------
# The objective


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


@dataclass
class _State:
    R: np.ndarray  # (3, 3) R_cam_obj
    b: np.ndarray  # (3,) box centre, or bottom-face centre on the plane in plane mode
    log_s: np.ndarray  # (3,)

    def copy(self) -> _State:
        return _State(self.R.copy(), self.b.copy(), self.log_s.copy())


@dataclass
class _Problem:
    """Everything that stays fixed while one hypothesis is optimised."""

    obs: np.ndarray  # (N, 3) camera frame
    obs_tree: cKDTree
    prior_p: np.ndarray  # (M, 3) unit box
    prior_n: np.ndarray  # (M, 3)
    up: np.ndarray | None
    plane: tuple[np.ndarray, float] | None
    basis: np.ndarray  # (9, D): (d_omega, d_b, d_log_s) = basis @ delta
    log_aspect: np.ndarray  # (3,) log of the prior's metric aspect
    config: FitConfig
    scene: SceneView | None = None
    iterations: int = field(default=0)
    # the last `_evaluate` ([state, result, terms of its normal equations]): the final scoring of a fit
    # re-evaluates the state the optimiser ended on; and the observation's unit rays, computed once
    memo: list | None = field(default=None, repr=False, compare=False)
    rays: np.ndarray | None = field(default=None, repr=False, compare=False)
    # a body of revolution (y_continuous): the containment term holds the points in its inscribed cylinder
    round_section: bool = False
    # `scene` is used for its image bounds only (coarse stages of an object the image border cuts off)
    scene_image_only: bool = False
    # per extent pair (x:y, y:z, x:z), `config.aspect_weight` times the prior's family's factors
    # (`ShapeFamily.aspect_weight_factors`)
    aspect_factors: np.ndarray = field(default_factory=lambda: np.ones(3))

    def centre(self, st: _State) -> np.ndarray:
        if self.plane is None:
            return st.b
        assert self.up is not None
        return st.b + 0.5 * math.exp(st.log_s[1]) * self.up

    def pose(self, st: _State) -> Pose9D:
        return Pose9D(st.R, self.centre(st), np.exp(st.log_s))


def _huber_weights(d: np.ndarray, delta: float) -> np.ndarray:
    w = np.ones_like(d)
    far = d > delta
    w[far] = delta / d[far]
    return w


def _huber_cost(d: np.ndarray, delta: float) -> np.ndarray:
    """Huber cost in squared-distance units: d^2 near, 2 delta d - delta^2 beyond delta."""
    return np.where(d <= delta, d * d, 2.0 * delta * d - delta * delta)


def _not_self_occluded(x: np.ndarray, size: np.ndarray, cos_view: np.ndarray) -> np.ndarray:
    """(M,) bool: posed prior points `x` (M, 3) not hidden behind the prior's own nearer surface.

    A coarse z-buffer of the posed points: image-plane bins of about two point spacings (the spacing from
    the box's surface area over M), and a point is hidden when the nearest point of its bin is in front of
    it by more than its own surface's depth change across a bin (bin width x tan of its viewing angle) plus
    5 mm. Without it a laptop seen from behind its screen lets the hidden keyboard pull onto the screen
    and the box collapses to the screen's thickness.
    """
    area = 2.0 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2])
    bin_m = 2.0 * math.sqrt(area / len(x))
    z = x[:, 2]
    h = len(z) // 2  # the median as np.median computes it (a partition, the mean of the middle pair)
    if len(z) % 2:
        z_ref = float(np.partition(z, h)[h])
    else:
        zp = np.partition(z, (h - 1, h))
        z_ref = float((zp[h - 1] + zp[h]) / 2.0)
    if z_ref <= 0.0:
        return np.ones(len(x), dtype=bool)
    b = bin_m / z_ref
    with np.errstate(divide="ignore", invalid="ignore"):
        iu = np.floor(x[:, 0] / (z * b))
        iv = np.floor(x[:, 1] / (z * b))
    ok = np.isfinite(iu) & np.isfinite(iv) & (z > 0.0)
    if not np.all(ok):
        return np.ones(len(x), dtype=bool)
    iu -= iu.min()
    iv -= iv.min()
    key = (iu * (iv.max() + 1.0) + iv).astype(np.int64)
    z_min = np.full(int(key.max()) + 1, np.inf)
    np.minimum.at(z_min, key, z)
    c = np.clip(cos_view, 1e-3, 1.0)
    tol = 0.005 + bin_m * np.sqrt(1.0 - c * c) / c
    return z <= z_min[key] + tol


def _evaluate(pb: _Problem, st: _State, want_jacobian: bool):
    """Robust objective at `st` and, if asked, its Gauss-Newton normal equations in the reduced params.

    The last evaluation is remembered (`_Problem.memo`, by the state's identity: states are never changed in
    place), with its nearest neighbours: asking again for the same state returns it, and asking for the
    normal equations of a state whose cost alone was asked for (`_optimise`'s accepted trial step) builds
    them on its correspondences, without another pair of nearest-neighbour queries.
    """
    memo = pb.memo
    if memo is None or memo[0] is not st:
        memo = pb.memo = [st, *_objective(pb, st)]
    if want_jacobian and memo[1][3] is None:
        H, g = _jacobian(pb, st, memo[2])
        memo[1] = (*memo[1][:3], H, g)
    return memo[1]


def _objective(pb: _Problem, st: _State):
    """The objective at `st`: ((cost, obs->prior mean d^2, prior->obs mean d^2, None, None), the terms its
    normal equations need)."""
    s = np.exp(st.log_s)
    t = pb.centre(st)
    RT = st.R.T
    q = (pb.prior_p * s) @ RT  # (M, 3) R diag(s) p
    x = q + t
    n_cam = (pb.prior_n / s) @ RT
    # facing the camera: cos(normal, -x) > visible_cos, i.e. -n.x > visible_cos |n| |x|
    facing = -np.einsum("ij,ij->i", n_cam, x)
    # |n| |x| as np.linalg.norm computes each (sqrt of the sum of squares), without its overheads
    cos_view = facing / (
        np.sqrt(np.add.reduce(n_cam * n_cam, axis=1)) * np.sqrt(np.add.reduce(x * x, axis=1))
    )
    visible = cos_view > pb.config.visible_cos
    if pb.config.self_occlusion:
        visible &= _not_self_occluded(x, s, cos_view)
    if pb.scene is not None:
        idx = np.flatnonzero(visible)  # only the points still in: the projection costs per point
        if pb.scene_image_only:
            visible[idx] = _pixels(pb.scene.intrinsics, x[idx])[0]
        else:
            visible[idx] = _observable(pb.scene, x[idx], pb.config.occlusion_margin_m)
    delta = pb.config.huber_m

    # observation -> prior: every prior point may be the nearest one (see module docstring);
    # prior -> observation: visible prior points only
    vis_idx = np.flatnonzero(visible)
    if len(vis_idx) == 0:  # a degenerate pose; keep the term defined with all points
        vis_idx = np.arange(len(x))
    # unbalanced, non-compact, 32-point leaves: cheapest to build and query for the few hundred points of a
    # warm fit or a coarse stage (the nearest neighbours are exact whatever the tree's layout)
    d_op, j_op = cKDTree(x, leafsize=32, balanced_tree=False, compact_nodes=False).query(pb.obs, k=1)
    d_po, j_po = pb.obs_tree.query(x[vis_idx], k=1)
    op, po = float(np.mean(d_op * d_op)), float(np.mean(d_po * d_po))
    cost = float(_huber_cost(d_op, delta).mean() + _huber_cost(d_po, delta).mean())
    aspect_r = _aspect_residuals(pb, st.log_s)
    cost += float(aspect_r @ aspect_r)
    contain_cost, contain_part = _containment_cost(pb, st, s, t)
    cost += contain_cost
    return (cost, op, po, None, None), (s, q, x, d_op, j_op, d_po, j_po, vis_idx, aspect_r, contain_part)


def _jacobian(pb: _Problem, st: _State, terms: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton normal equations (H, g) in the reduced params at `st`, on the correspondences and
    residuals `_objective` found there."""
    s, q, x, d_op, j_op, d_po, j_po, vis_idx, aspect_r, contain_part = terms
    delta = pb.config.huber_m
    n_obs, n_vis = len(pb.obs), len(vis_idx)
    # Residuals r = x_k - y_j, weights w / n so that sum w r^2 is the objective.
    k_all = np.concatenate([j_op, vis_idx])
    y_all = np.concatenate([pb.obs, pb.obs[j_po]])
    w_all = np.concatenate([_huber_weights(d_op, delta) / n_obs, _huber_weights(d_po, delta) / n_vis])
    r = x[k_all] - y_all  # (K, 3)
    qk = q[k_all]
    ak = pb.prior_p[k_all] * s  # (K, 3) s * p: dx/dlog s_i = R[:, i] a_i
    u = 0.5 * s[1] * pb.up if pb.plane is not None else None  # bottom held on the plane: + u on log s_y
    H9, g9 = _normal_equations(qk, ak, r, w_all, st.R, u)
    H = pb.basis.T @ H9 @ pb.basis
    g = pb.basis.T @ g9
    # aspect prior: residuals linear in log s
    Ja = _aspect_jacobian(pb) @ pb.basis[6:9]
    H += Ja.T @ Ja
    g += Ja.T @ aspect_r
    if contain_part is not None:
        Jc, wc, ec = _containment_jacobian(pb, st, s, contain_part)
        Jc = Jc @ pb.basis
        H += Jc.T @ (Jc * wc[:, None])
        g += Jc.T @ (wc * ec)
    return H, g


def _containment_cost(pb: _Problem, st: _State, s: np.ndarray, t: np.ndarray) -> tuple[float, tuple | None]:
    """Containment term's cost, and what its Jacobian needs (`_containment_jacobian`; None when no point
    pulls).

    Residual per observed point y and box axis i: e = |l_i| - s_i / 2 - margin when positive, with
    l = R^T (y - t) the point in box axes; Huber-weighted, averaged over the observed points, times
    `contain_weight`. A body of revolution (`_Problem.round_section`) holds its points in the cylinder
    inscribed in the box instead: its x and z residuals become one radial one, e = |(l_x, l_z)| - s_x / 2
    - margin (s_x = s_z for it). Parameters as in `_normal_equations` (left rotation increment, centre or
    bottom, log size); with a plane, the centre moves with log s_y (bottom held).
    """
    lam = pb.config.contain_weight
    if lam <= 0.0:
        return 0.0, None
    d = pb.obs - t
    loc = d @ st.R
    # depth noise moves a point along its ray: along a direction u (box axes) it adds |R u . ray| of it
    if pb.rays is None:  # the observation's unit rays, once per problem
        pb.rays = pb.obs / np.linalg.norm(pb.obs, axis=1, keepdims=True)
    ray_loc = pb.rays @ st.R
    if pb.round_section:
        rho = np.hypot(loc[:, 0], loc[:, 2])
        radial = np.zeros_like(loc)  # (N, 3) the unit radial direction of each point, box axes
        on_axis = rho < 1e-9  # a point on the axis: any radial direction, +x
        safe = np.where(on_axis, 1.0, rho)
        radial[:, 0] = np.where(on_axis, 1.0, loc[:, 0] / safe)
        radial[:, 2] = np.where(on_axis, 0.0, loc[:, 2] / safe)
        extent = np.column_stack([rho, np.abs(loc[:, 1])])
        half = np.array([0.25 * (s[0] + s[2]), 0.5 * s[1]])
        along = np.column_stack([np.einsum("ij,ij->i", ray_loc, radial), ray_loc[:, 1]])
    else:
        radial = None
        extent, half, along = np.abs(loc), 0.5 * s, ray_loc
    margin = pb.config.contain_margin_m + pb.config.contain_ray_margin_m * np.abs(along)
    exc = extent - half - margin
    cap = pb.config.contain_cap_m
    n = len(pb.obs)
    delta = pb.config.huber_m
    # outliers beyond the cap cost a constant (the cap's cost, `_huber_cost` in scalars) and do not pull
    n_out = int(np.count_nonzero(exc > cap))
    k_pt, k_ax = np.nonzero((exc > 0.0) & (exc <= cap))
    cost_out = lam * n_out * (cap * cap if cap <= delta else 2.0 * delta * cap - delta * delta) / n
    if len(k_pt) == 0:
        return cost_out, None
    e = exc[k_pt, k_ax]
    # each residual's outward direction (box axes) and d e / d log s
    out_loc = np.zeros((len(e), 3))
    ds = np.zeros((len(e), 3))
    if radial is not None:
        side = k_ax == 0
        out_loc[side] = radial[k_pt[side]]
        ds[side, 0], ds[side, 2] = -0.25 * s[0], -0.25 * s[2]
        top = ~side
        out_loc[top, 1] = np.sign(loc[k_pt[top], 1])
        ds[top, 1] = -0.5 * s[1]
    else:
        out_loc[np.arange(len(e)), k_ax] = np.sign(loc[k_pt, k_ax])
        ds[np.arange(len(e)), k_ax] = -0.5 * s[k_ax]
    return cost_out + lam * float(_huber_cost(e, delta).sum()) / n, (d[k_pt], out_loc @ st.R.T, ds, e)


def _containment_jacobian(pb: _Problem, st: _State, s: np.ndarray, part: tuple):
    """The containment term's (J (K, 9), weights (K,), residuals (K,)) from `_containment_cost`'s terms."""
    d, out, ds, e = part  # per residual: the point minus the centre, its outward unit direction (camera)
    J = np.zeros((len(e), 9))
    J[:, 0:3] = _cross_rows(out, d)  # d (out . R^T d) / d omega = out x d
    J[:, 3:6] = -out
    J[:, 6:9] = ds
    if pb.plane is not None:
        assert pb.up is not None
        J[:, 7] += -(out @ pb.up) * 0.5 * s[1]  # the centre rises with the height (bottom held)
    w = pb.config.contain_weight * _huber_weights(e, pb.config.huber_m) / len(pb.obs)
    return J, w, e


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (K, 3) arrays (np.cross spends more time on axis handling than on maths)."""
    return np.column_stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ]
    )


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _normal_equations(
    q: np.ndarray, a: np.ndarray, r: np.ndarray, w: np.ndarray, R: np.ndarray, u: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton H = sum w J^T J (9, 9) and g = sum w J^T r (9,) from weighted moments, in closed form.

    Per residual r_k = x_k - y_k with x_k = R diag(s) p_k + t and parameters (left rotation increment,
    translation, log size), J_k = [-hat(q_k), I, R diag(a_k)] with q_k = R a_k, a_k = s * p_k, plus the
    constant column u on log s_y when the bottom face is held on the plane. Sums of 3x3 moments replace the
    (3K, 9) Jacobian, which costs K times more memory traffic.
    """
    W = float(w.sum())
    wq = q * w[:, None]
    wa = a * w[:, None]
    sum_q, sum_a, sum_r = wq.sum(axis=0), wa.sum(axis=0), w @ r
    Q = q.T @ wq  # sum w q q^T
    P = wq.T @ a  # sum w q a^T
    H = np.zeros((9, 9))
    H[0:3, 0:3] = np.trace(Q) * np.eye(3) - Q  # sum w hat(q)^T hat(q)
    H[0:3, 3:6] = _hat(sum_q)  # sum w (-hat(q))^T I
    H[0:3, 6:9] = _cross_rows(P.T, R.T).T  # column i: (sum w a_i q) x R[:, i]
    H[3:6, 3:6] = W * np.eye(3)
    H[3:6, 6:9] = R * sum_a  # sum w R diag(a)
    H[6:9, 6:9] = np.diag(np.einsum("ij,ij->j", wa, a))  # sum w diag(a)^2
    H[3:6, 0:3] = H[0:3, 3:6].T
    H[6:9, 0:3] = H[0:3, 6:9].T
    H[6:9, 3:6] = H[3:6, 6:9].T
    g = np.empty(9)
    g[0:3] = _cross_rows(wq, r).sum(axis=0)  # sum w hat(q) r
    g[3:6] = sum_r
    g[6:9] = np.einsum("ij,ij->j", wa, r @ R)  # sum w a * (R^T r)
    if u is not None:
        v = np.concatenate([_hat(sum_q) @ u, W * u, sum_a * (R.T @ u)])  # sum w J0^T u
        H[7, :] += v
        H[:, 7] += v
        H[7, 7] += W * float(u @ u)
        g[7] += float(u @ sum_r)
    return H, g


_PAIRS = np.array([[0, 1], [1, 2], [0, 2]])


def _aspect_residuals(pb: _Problem, log_s: np.ndarray) -> np.ndarray:
    w = pb.config.aspect_weight * pb.aspect_factors
    diff = log_s[_PAIRS[:, 0]] - log_s[_PAIRS[:, 1]]
    target = pb.log_aspect[_PAIRS[:, 0]] - pb.log_aspect[_PAIRS[:, 1]]
    return w * (diff - target)


def _aspect_jacobian(pb: _Problem) -> np.ndarray:
    J = np.zeros((3, 3))
    J[np.arange(3), _PAIRS[:, 0]] = 1.0
    J[np.arange(3), _PAIRS[:, 1]] = -1.0
    return pb.config.aspect_weight * pb.aspect_factors[:, None] * J


def _rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (3,) by Rodrigues' formula: `so3_exp` up to round-off, without
    scipy's per-call overheads (it runs once per Levenberg-Marquardt step)."""
    theta2 = float(w @ w)
    W = _hat(w)
    if theta2 < 1e-16:  # second-order series: exact to double precision below 1e-8 rad
        return np.eye(3) + W + 0.5 * (W @ W)
    theta = math.sqrt(theta2)
    return np.eye(3) + (math.sin(theta) / theta) * W + ((1.0 - math.cos(theta)) / theta2) * (W @ W)


def _apply(pb: _Problem, st: _State, delta: np.ndarray) -> _State:
    full = pb.basis @ delta
    return _State(
        _rotvec_matrix(full[0:3]) @ st.R,
        st.b + full[3:6],
        np.clip(st.log_s + full[6:9], _LOG_SIZE_MIN, _LOG_SIZE_MAX),
    )


def _optimise(pb: _Problem, st: _State, iterations: int) -> tuple[_State, float]:
    """Levenberg-Marquardt on the robust objective with correspondences re-found every iteration."""
    cost, _, _, H, g = _evaluate(pb, st, iterations > 0)  # no iteration, no normal equations
    mu = pb.config.damping
    for _ in range(iterations):
        pb.iterations += 1
        assert H is not None and g is not None
        scale = float(np.mean(np.diag(H))) or 1.0
        D = H.shape[0]
        try:
            delta = -np.linalg.solve(H + (mu * scale) * np.eye(D), g)
        except np.linalg.LinAlgError:
            break
        trial = _apply(pb, st, delta)
        t_cost = _evaluate(pb, trial, False)[0]  # the normal equations only for a step that is taken
        if t_cost <= cost:
            st, cost, H, g = trial, t_cost, *_evaluate(pb, trial, True)[3:]
            mu = max(mu / 3.0, pb.config.damping)
            if float(np.max(np.abs(delta))) < pb.config.step_tol:
                break
        else:
            mu *= 10.0
            if mu > 1e6:
                break
    return st, cost


# --------------------------------------------------------------------------------------------------------
# Hypotheses


def _plane_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane orthogonal to `up` (e1 the camera x direction projected)."""
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2


def _R_from_yaw(up: np.ndarray, e1: np.ndarray, e2: np.ndarray, yaw: float) -> np.ndarray:
    x = math.cos(yaw) * e1 + math.sin(yaw) * e2
    z = np.cross(x, up)
    return np.column_stack([x, up, z])


def _proper_axis_rotations(U: np.ndarray, symmetry: str) -> list[np.ndarray]:
    """Rotations whose columns are signed, permuted columns of the PCA frame `U` (24 proper ones)."""
    out = []
    seen_y = set()
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for sx in (1.0, -1.0):
            for sy in (1.0, -1.0):
                for sz in (1.0, -1.0):
                    R = U[:, perm] * np.array([sx, sy, sz])
                    if np.linalg.det(R) < 0.0:
                        continue
                    if symmetry in ("y_continuous", "spherical"):
                        key = (perm[1], sy)
                        if key in seen_y:
                            continue
                        seen_y.add(key)
                    out.append(R)
    return out


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


def _cut_sides(local: np.ndarray, lo: np.ndarray, hi: np.ndarray, cut_edge: np.ndarray) -> np.ndarray:
    """(3, 2) bool: which sides (low, high) of each box axis the image border or an occluder cuts off
    (`geometry.occlusion.cut_ends` with `_CUT_SHARE`), from the points in box axes `local` (N, 3), their 2nd
    and 98th percentiles `lo`, `hi` (3,) and which of them lie on a cut edge (`cut_edge`, (N,))."""
    return cut_ends(local, lo, hi, cut_edge, _CUT_SHARE)


def _initial_state(
    pts: np.ndarray,
    R: np.ndarray,
    prior: ShapePrior,
    up: np.ndarray | None,
    plane,
    symmetry: str,
    widen: float = 1.0,
    cut_edge: np.ndarray | None = None,
) -> _State:
    """Amodal initial box for the rotation `R`: visible extents as lower bounds, prior aspect for the rest,
    grown away from the camera; bottom on the plane when one is given.

    `cut_edge` (N,) marks the points on the image border (`_on_border`) or an occluder's edge
    (`_next_to_occluder`): a side they cut off (`_cut_sides`) is not seen where it ends, so its axis takes
    its size from the prior's aspect scaled to the uncut axes, and the box grows across the cut there (the
    fit cannot tell: the prior's points beyond the image or behind the occluder do not pull)."""
    local = pts @ R  # object-axis coordinates of the points (origin at the camera)
    lo = np.percentile(local, 2.0, axis=0)
    hi = np.percentile(local, 98.0, axis=0)
    ext = np.maximum(hi - lo, 1e-3)
    cut = np.zeros((3, 2), dtype=bool) if cut_edge is None else _cut_sides(local, lo, hi, cut_edge)
    if plane is not None:
        normal, d = plane
        heights = pts @ normal + d
        top = float(np.percentile(heights, 98.0))
        ext[1] = max(top, 1e-3)
        cut[1, 0] = False  # the bottom rests on the plane, seen or not
    aspect = prior.aspect
    axis_cut = cut.any(axis=1)
    if symmetry in ("y_continuous", "spherical"):
        ext[0] = ext[2] = max(ext[0], ext[2])
        axis_cut[[0, 2]] = axis_cut[0] or axis_cut[2]  # one section width
    # Scale of the prior's aspect that just covers the seen extents along the best-seen axes: the two best of
    # an uncut box, and of a cut one its best uncut axis (besides the cut one, the third is the depth
    # direction, seen shorter: an occluded mug seen as a sliver took its width from its depth). An axis seen
    # shorter than that is grown to it, a cut one to the aspect itself.
    ratio = ext / aspect
    free = np.sort(ratio[~axis_cut]) if not axis_cut.all() else np.sort(ratio)
    kappa = float(free[-1] if axis_cut.any() else free[1])
    size = np.maximum(ext, kappa * aspect * np.where(axis_cut, 1.0, 0.9))
    if symmetry in ("y_continuous", "spherical"):
        size[0] = size[2] = max(size[0], size[2])
    size[[0, 2]] *= widen
    centre_local = 0.5 * (lo + hi)
    # grow the box away from the camera (the seen face stays where it is), or across the cut
    view = pts.mean(axis=0) @ R  # camera -> object direction in object axes (unnormalised)
    direction = np.where(cut[:, 0] | cut[:, 1], cut[:, 1].astype(float) - cut[:, 0], np.sign(view))
    grow = size - ext
    centre_local = centre_local + 0.5 * grow * direction
    centre = R @ centre_local
    if plane is not None:
        normal, d = plane
        if not cut[1, 1]:
            size[1] = ext[1]
        bottom = centre - (centre @ normal + d) * normal
        return _State(R.copy(), bottom, np.log(size))
    return _State(R.copy(), centre, np.log(size))


def _basis(up: np.ndarray | None, plane, symmetry: str) -> np.ndarray:
    cols = []
    e = np.eye(9)
    if up is None:
        cols += [e[0], e[1], e[2]]
    else:
        cols.append(np.concatenate([up, np.zeros(6)]))
    if plane is None:
        cols += [e[3], e[4], e[5]]
    else:
        e1, e2 = _plane_basis(plane[0])
        cols += [
            np.concatenate([np.zeros(3), e1, np.zeros(3)]),
            np.concatenate([np.zeros(3), e2, np.zeros(3)]),
        ]
    if symmetry in ("y_continuous",):
        cols += [e[6] + e[8], e[7]]
    elif symmetry == "spherical":
        cols += [e[6] + e[7] + e[8]]
    else:
        cols += [e[6], e[7], e[8]]
    return np.column_stack(cols)


def _turn_about_body(pb: _Problem, st: _State, axis_xz: np.ndarray, angle: float) -> _State:
    """`st` turned by `angle` [rad] about the vertical line through its posed round-body axis (`axis_xz`,
    unit-box x and z): the body stays where it is, the protrusion (a mug's handle) and with it the box
    centre swing round. Upright fits only."""
    assert pb.up is not None
    up = pb.up
    s = np.exp(st.log_s)
    lever = np.array([s[0] * axis_xz[0], s[2] * axis_xz[1]])
    axis_pt = pb.centre(st) + st.R[:, 0] * lever[0] + st.R[:, 2] * lever[1]
    R = so3_exp(up * angle) @ st.R
    centre = axis_pt - R[:, 0] * lever[0] - R[:, 2] * lever[1]
    b = centre - 0.5 * s[1] * up if pb.plane is not None else centre
    return _State(R, b, st.log_s.copy())


def protrusion_points(pose: Pose9D, axis_xz: np.ndarray, pts: np.ndarray, margin: float) -> np.ndarray:
    """The observed points `pts` outside the posed round body by more than `margin` [m]: points only the
    protrusion (a mug's handle) explains (`priors.library.round_body_axis`)."""
    return pts[_body_ellipse((pts - pose.t) @ pose.R, axis_xz, pose.size, margin) > 1.0]


def _body_ellipse(local: np.ndarray, axis_xz: np.ndarray, size: np.ndarray, margin: float) -> np.ndarray:
    """(N,) elliptic radius of object-frame points about the round body's axis: 1 on the body's side wall
    grown by `margin` [m], > 1 outside it (the ellipse reaches the box's -x face and its z faces)."""
    rx = (axis_xz[0] + 0.5) * size[0] + margin
    rz = 0.5 * size[2] + margin
    dx = local[:, 0] - axis_xz[0] * size[0]
    dz = local[:, 2] - axis_xz[1] * size[2]
    return np.sqrt((dx / rx) ** 2 + (dz / rz) ** 2)


#: Prior points of the protrusion (outside the round body by 5 % of its radius), per prior.
_PROTRUSION: weakref.WeakKeyDictionary[ShapePrior, tuple[np.ndarray, np.ndarray]] = (
    weakref.WeakKeyDictionary()
)


def _handle_yaw(
    pb: _Problem,
    st: _State,
    axis_xz: np.ndarray,
    prior: ShapePrior,
    seen: np.ndarray,
    range_deg: float,
    coarse_deg: float = 3.0,
) -> tuple[_State, float]:
    """`st` turned about the round body's axis (within +-`range_deg`, to 1 deg) to the turn whose visible
    protrusion points (the prior's handle, facing the camera) lie closest to the observed protrusion points
    `seen` (mean squared distance, each capped at 1 cm), and that cost [m^2] (inf when no turn shows the
    handle)."""
    cached = _PROTRUSION.get(prior)
    if cached is None:
        P = np.asarray(prior.points, dtype=np.float64)
        unit = np.array([1.0, 1.0, 1.0])
        keep = _body_ellipse(P, axis_xz, unit, 0.0) > 1.05
        cached = (P[keep], np.asarray(prior.normals, dtype=np.float64)[keep])
        _PROTRUSION[prior] = cached
    hp, hn = cached
    if len(hp) < 4:
        return st, math.inf
    s = np.exp(st.log_s)
    tried: dict[float, tuple[float, _State]] = {}

    def cost_at(a: float) -> float:
        if a not in tried:
            cand = st if a == 0.0 else _turn_about_body(pb, st, axis_xz, math.radians(a))
            x = (hp * s) @ cand.R.T + pb.centre(cand)
            facing = np.einsum("ij,ij->i", (hn / s) @ cand.R.T, x) < 0.0
            cost = math.inf
            if np.count_nonzero(facing) >= 4:
                d, _ = cKDTree(x[facing]).query(seen, k=1)
                cost = float(np.mean(np.minimum(d, 0.01) ** 2))
            tried[a] = (cost, cand)
        return tried[a][0]

    # coarse steps over the range, then finer steps round the best (1 deg at the end)
    rng = min(range_deg, 180.0)
    a0 = min([*np.arange(-rng, rng + 0.5, coarse_deg).tolist(), 0.0], key=cost_at)
    a1 = min((a0 + d for d in (-2.0, -1.0, 0.0, 1.0, 2.0)), key=cost_at)
    cost = tried[a1][0]
    return (tried[a1][1] if math.isfinite(cost) else st), cost


def _middle_of_flat_band(pb: _Problem, st: _State, axis_xz: np.ndarray, cfg: FitConfig) -> _State | None:
    """For a round body with a protrusion (a mug): the loss over turns of the protrusion about the body's
    axis, every `handle_scan_step_deg` round the circle; the turns whose loss is within `handle_band_tol`
    of the least form a band around it. A seen handle makes the band narrow (its points must be matched):
    then None (keep the optimum). A hidden one leaves it wide (every turn that keeps the handle out of
    sight explains the points equally): then the state turned to the middle of the band."""
    n = max(3, round(360.0 / cfg.handle_scan_step_deg))
    angles = 2.0 * math.pi * np.arange(n) / n
    costs = np.array([_evaluate(pb, st if k == 0 else _turn_about_body(pb, st, axis_xz, float(a)), False)[0]
                      for k, a in enumerate(angles)])  # fmt: skip
    k0 = int(np.argmin(costs))
    flat = costs <= (1.0 + cfg.handle_band_tol) * costs[k0]
    lo = hi = 0  # steps from k0 to the band's ends, round the circle
    while lo < n - 1 and flat[(k0 - lo - 1) % n]:
        lo += 1
    while hi < n - 1 - lo and flat[(k0 + hi + 1) % n]:
        hi += 1
    log.debug("handle band: %d of %d turns within %.2f of the least", lo + hi + 1, n, cfg.handle_band_tol)
    if lo + hi + 1 < cfg.handle_band_min:
        return None
    middle = angles[k0] + 0.5 * (hi - lo) * (2.0 * math.pi / n)
    return _turn_about_body(pb, st, axis_xz, float(middle))


# --------------------------------------------------------------------------------------------------------
# Symmetry-canonical output


def _rot_about(axis: np.ndarray, angle: float) -> np.ndarray:
    return so3_exp(axis * angle)


def canonicalize_symmetry(pose: Pose9D, symmetry: str, up_cam: ArrayLike | None = None) -> Pose9D:
    """The representative of `pose` under the shape's symmetry group that this library reports.

    - `y_continuous`: the object's y axis is kept; x and z turn about it so that +z points as nearly as
      possible towards the camera (z is the unit projection of -t on the plane orthogonal to y).
    - `x_continuous`: +x is flipped (end-over-end) to have a non-negative camera-x component, then y and z
      turn about x so that +y points as nearly as possible to the camera's up (-y_cam), or to `up_cam`.
    - `box` / `y_2fold`: among the 180-degree turns of the group (about y only for y_2fold, and for box when
      `up_cam` is given and y is up), the one whose +z faces the camera most, with +y up first for box.
    - `spherical`: R = identity; the size becomes the mean of the three.
    - `none`: unchanged.
    """
    sym = symmetry
    if sym not in SYMMETRIES:
        raise InvalidInputError(f"symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
    R, t, size = pose.R.copy(), pose.t, pose.size.copy()
    to_cam = -t / max(float(np.linalg.norm(t)), 1e-12)
    up = _check_unit(up_cam, "up_cam")
    if sym == "y_continuous":
        y = R[:, 1]
        z = to_cam - (to_cam @ y) * y
        if np.linalg.norm(z) > 1e-6:
            z /= np.linalg.norm(z)
            x = np.cross(y, z)
            R = np.column_stack([x, y, z])
        size[0] = size[2] = 0.5 * (size[0] + size[2])
    elif sym == "x_continuous":
        x = R[:, 0]
        if x[0] < 0.0:
            R = R @ np.diag([-1.0, -1.0, 1.0])  # 180 degrees about z keeps the shape (end-over-end)
            x = R[:, 0]
        ref = up if up is not None else np.array([0.0, -1.0, 0.0])
        y = ref - (ref @ x) * x
        if np.linalg.norm(y) > 1e-6:
            y /= np.linalg.norm(y)
            R = np.column_stack([x, y, np.cross(x, y)])
        size[1] = size[2] = 0.5 * (size[1] + size[2])
    elif sym in ("box", "y_2fold"):
        flips = [np.eye(3), np.diag([-1.0, 1.0, -1.0])]
        if sym == "box":
            flips += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
        ref_up = up if up is not None else np.array([0.0, -1.0, 0.0])

        def score(Rc: np.ndarray) -> tuple[float, float]:
            return (round(float(Rc[:, 1] @ ref_up), 9), float(Rc[:, 2] @ to_cam))

        R = max((R @ F for F in flips), key=score)
    elif sym == "spherical":
        R = np.eye(3)
        size[:] = float(np.mean(size))
    return Pose9D(project_to_so3(R), t, size)


def seen_surface(
    pose: Pose9D, plane: tuple[np.ndarray, float] | None, config: FitConfig, scene: SceneView | None
) -> np.ndarray:
    """(M, 3) camera-frame points of the object's seen surface next to the fitted box `pose` [m]; (0, 3)
    without a `scene`.

    Which points count (the `grow_*` settings of `FitConfig`):

    - the points of the scene's mask at its own median depth (`grow_median_px`), not the raw points: depth
      noise along the rays moves silhouette points sideways, out of the true box by up to a centimetre on a
      far object;
    - with a support plane, only points more than `grow_plane_clearance_m` above it (table pixels that a
      mask took in);
    - points with more than `grow_density_min` neighbours within the link radius (`grow_density_radius_m`,
      or `grow_density_spacings` times the points' median spacing where they are sparser): a flying pixel or
      a stray mask pixel has none;
    - the pieces connected (through such points, at the link radius) to the box's inside: a strip of the
      background or of another object that the mask bled onto lies apart from the object.

    At most about 4096 points (an even stride over the mask): the extents and the shape seen from above,
    not every pixel.
    """
    empty = np.zeros((0, 3))
    if scene is None:
        return empty
    points = back_project(masked_median_depth(scene.depth_m, scene.mask, config.grow_median_px),
                          scene.intrinsics)  # fmt: skip
    pts = points[:: max(1, len(points) // 4096)]
    if plane is not None:
        pts = pts[pts @ plane[0] + plane[1] > config.grow_plane_clearance_m]
    if len(pts) < 2:
        return empty
    tree = cKDTree(pts)
    # the points' own spacing sets the link radius: a far or small object is sampled sparsely
    spacing = float(np.median(tree.query(pts, k=2)[0][:, 1]))
    link = max(config.grow_density_radius_m, config.grow_density_spacings * spacing)
    # one neighbour query serves both tests: a point's neighbours are its pairs (and itself)
    pairs = tree.query_pairs(link, output_type="ndarray")
    dense = np.bincount(pairs.ravel(), minlength=len(pts)) + 1 > config.grow_density_min
    if not np.any(dense):
        return empty
    pairs = pairs[dense[pairs[:, 0]] & dense[pairs[:, 1]]]  # the surface links through dense points only
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts)))
    _, label = connected_components(graph, directed=False)
    inside = dense & np.all(np.abs((pts - pose.t) @ pose.R) <= 0.5 * pose.size, axis=1)
    return pts[dense & np.isin(label, np.unique(label[inside]))]


def grow_to_seen(
    pose: Pose9D,
    symmetry: str,
    plane: tuple[np.ndarray, float] | None,
    config: FitConfig,
    scene: SceneView | None,
    surface: np.ndarray | None = None,
) -> Pose9D:
    """`pose` with each face moved out to the seen surface beyond it (never in).

    The seen surface lies inside the true box, so the extents of the observed points are lower bounds on the
    box. The fit's containment term holds only points within `contain_cap_m` of the box (mask bleed lies
    farther), so where the prior's shape differs from the instance's (a hammer's head, a curved banana, a
    teapot's spout on a superquadric) the fit leaves whole parts of the seen object outside.

    The surface is `seen_surface(pose, plane, config, scene)` (pass it as `surface` where it is already
    computed; without either nothing moves). A face moves out when at least `grow_min_points` of its points
    lie beyond it by more than `grow_margin_m`, to the `grow_min_points`-th farthest less that margin (the
    band the noise of the median depth spans). A round section (`y_continuous`) grows its radius about the
    fitted axis; an upright box's bottom stays on the plane. `grow_min_points` 0 turns it off.
    """
    k = config.grow_min_points
    if k <= 0:
        return pose
    if surface is None:
        surface = seen_surface(pose, plane, config, scene)
    if len(surface) < max(k, 2):
        return pose
    half = 0.5 * pose.size
    local = (surface - pose.t) @ pose.R
    lo, hi = -half.copy(), half.copy()
    margin = config.grow_margin_m

    def reach(excess: np.ndarray) -> float:
        """How far out the face goes: the k-th largest excess, less the margin (the noise band), or 0."""
        beyond = excess[excess > margin]
        if len(beyond) < k:
            return 0.0
        return float(np.partition(beyond, len(beyond) - k)[len(beyond) - k]) - margin

    axes = (1,) if symmetry == "y_continuous" else (0, 1, 2)
    for a in axes:
        hi[a] += reach(local[:, a] - half[a])
        lo[a] -= reach(-half[a] - local[:, a])
    if plane is not None and pose.R[:, 1] @ plane[0] > 0.9:
        lo[1] = -half[1]  # an upright box's bottom rests on the plane; only points above it are seen
    if symmetry == "y_continuous":
        radius = max(half[0], half[2])
        grown = radius + reach(np.hypot(local[:, 0], local[:, 2]) - radius)
        lo[[0, 2]], hi[[0, 2]] = -grown, grown
    if np.all(lo == -half) and np.all(hi == half):
        return pose
    return Pose9D(pose.R, pose.t + pose.R @ (0.5 * (lo + hi)), hi - lo)


# --------------------------------------------------------------------------------------------------------
# The public entry point


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


def fit_pose(
    points_cam: ArrayLike,
    prior: ShapePrior,
    config: FitConfig | None = None,
    up_cam: ArrayLike | None = None,
    init: Pose9D | None = None,
    support_plane_cam: ArrayLike | None = None,
    scene: SceneView | None = None,
) -> FitResult:
    """Fit the prior's metric 9-DoF box to the observed points by minimising the visibility-aware L_geo.

    Args:
        points_cam: (N, 3) float, metres: the object's masked depth back-projected into the camera frame
            (OpenCV: x right, y down, z forward); finite, z > 0, N >= `config.min_points`.
        prior: the canonical shape prior (unit box, +y up) with normals and symmetry tag.
        config: `FitConfig()` by default.
        up_cam: (3,) the support's up direction in the camera frame (unit or not; it is normalised). When
            given, the object stands upright on the support: its +y is `up_cam` and only yaw is searched.
        init: a warm start (e.g. the previous frame's pose): one hypothesis, fewer iterations, a random
            subsample of `config.n_points_warm` points instead of FPS.
        support_plane_cam: (4,) (nx, ny, nz, d) of the plane the object rests on, n.x + d = 0 in the camera
            frame with n pointing up (towards the object). Implies `up_cam` = n, and holds the box's bottom
            face on the plane: the amodal height reaches the support even where the bottom is hidden.
        scene: the depth image and mask the points came from (`SceneView`), optional: prior points the
            camera could not have seen there (outside the image, no reading, behind an occluder) do not
            pull on the observation (`config.scene_occlusion`).

    Returns:
        FitResult; `pose.size` > 0, `pose.R` symmetry-canonical for the prior's symmetry tag.

    Raises:
        InvalidInputError: wrong shapes, NaN/inf, points behind the camera, too few points, bad up/plane.
    """
    t0 = time.perf_counter()
    cfg = FitConfig() if config is None else config
    if not isinstance(cfg, FitConfig):
        raise InvalidInputError(f"config must be a FitConfig, got {type(cfg).__name__}")
    _check_prior(prior)
    pts_all = _check_points(points_cam, cfg.min_points)
    up = _check_unit(up_cam, "up_cam")
    plane = _check_plane(support_plane_cam, up)
    if plane is not None:
        up = plane[0]
    if init is not None and not isinstance(init, Pose9D):
        raise InvalidInputError(f"init must be a Pose9D or None, got {type(init).__name__}")
    if scene is not None and not isinstance(scene, SceneView):
        raise InvalidInputError(f"scene must be a SceneView or None, got {type(scene).__name__}")
    view = scene if cfg.scene_occlusion else None
    sym = prior.symmetry

    # 1. observation: depth gate, subsample, descriptor
    z = pts_all[:, 2]
    # percentiles of an even stride of at most ~8k points: as good for a gate, and O(N) work stays small
    z_lo, z_hi = np.percentile(z[:: max(1, len(z) // 8192)], cfg.clip_percentiles)
    gate = cfg.depth_gate_ratio * (z_hi - z_lo) + 0.01
    pts = pts_all[(z >= z_lo - gate) & (z <= z_hi + gate)]
    if len(pts) < cfg.min_points:
        raise InvalidInputError(
            f"only {len(pts)} points are left after the depth gate; the fit needs {cfg.min_points}"
        )
    warm = init is not None
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
    mode = "upright_plane" if plane is not None else ("upright" if up is not None else "free")
    if warm:
        mode = "warm_" + mode

    basis = _basis(up, plane, sym)
    # Articulated families (a laptop's screen angle) bring variants of the prior; they compete as extra
    # hypotheses at the best yaw of the mean shape (see the coarse stage below).
    variants = articulated_variants(prior) if cfg.articulations and not warm else ()
    shapes = (prior, *variants)
    problems: dict[tuple[int, int, int, bool, bool], _Problem] = {}

    # Points where the silhouette is not the object's own end, on the image border or an occluder's edge: the
    # sides they cut off take the prior's aspect (`_initial_state`). The coarse stages rank hypotheses
    # without the scene view, unless an occluder cuts the object (its seen sliver alone fits a thin slab
    # best: the right box lost the coarse ranking, dev split 29); for an object the border cuts they still
    # know the image's bounds. A warm start has none of this (its one stage has the whole scene view).
    cut_edge = None
    cut_by_image = cut_by_occluder = False
    if view is not None and not warm:
        on_border = _on_border(view.intrinsics, pts)
        by_occluder = _next_to_occluder(view, pts, cfg.occlusion_margin_m)
        cut_by_image, cut_by_occluder = bool(np.any(on_border)), bool(np.any(by_occluder))
        cut_edge = on_border | by_occluder

    def problem(k_shape: int, n_o: int, n_p: int, k_stage: int = len(cfg.stages) - 1) -> _Problem:
        late = k_stage >= len(cfg.stages) - cfg.occlusion_stages
        with_view = view is not None and (late or cut_by_occluder)
        image_only = not with_view and cut_by_image
        key = (k_shape, n_o, n_p, with_view, image_only)
        pb = problems.get(key)
        if pb is None:
            o = obs[:n_o]  # FPS order: a prefix is a coarser farthest-point sample
            shp = shapes[k_shape]
            pp, pn = _prior_subset(shp, n_p)
            tree = next((q.obs_tree for (_, m, *_), q in problems.items() if m == n_o), None)
            pb = _Problem(o, tree or cKDTree(o), pp, pn, up, plane, basis, np.log(shp.aspect), cfg,
                          view if with_view or image_only else None, round_section=sym == "y_continuous",
                          scene_image_only=image_only, aspect_factors=aspect_weight_factors(shp))  # fmt: skip
            problems[key] = pb
        return pb

    # 2. hypotheses
    if warm:
        assert init is not None
        R0 = init.R
        if up is not None:
            e1, e2 = _plane_basis(up)
            x0 = R0[:, 0] - (R0[:, 0] @ up) * up
            if np.linalg.norm(x0) < 1e-6:
                x0 = e1
            yaw = math.atan2(float(x0 @ e2), float(x0 @ e1))
            R0 = _R_from_yaw(up, e1, e2, yaw)
        size0 = np.asarray(init.size, dtype=np.float64)
        if plane is not None:
            bottom = init.t - 0.5 * size0[1] * up
            bottom = bottom - (bottom @ plane[0] + plane[1]) * plane[0]
            states = [_State(R0.copy(), bottom, np.log(size0))]
        else:
            states = [_State(R0.copy(), init.t.copy(), np.log(size0))]
    else:
        desc = robust_descriptor(pts, *cfg.clip_percentiles)
        if up is not None:
            e1, e2 = _plane_basis(up)
            c = pts - desc.centroid
            uv = np.column_stack([c @ e1, c @ e2])
            w, V = np.linalg.eigh(uv.T @ uv)
            major = V[:, int(np.argmax(w))]
            phi = math.atan2(major[1], major[0])
            n_yaw = _YAWS[sym]
            Rs = [_R_from_yaw(up, e1, e2, phi + 2.0 * math.pi * k / n_yaw) for k in range(n_yaw)]
            if sym in ("box", "x_continuous"):  # two-fold: yaw in [0, pi) suffices
                Rs = [_R_from_yaw(up, e1, e2, phi + math.pi * k / n_yaw) for k in range(n_yaw)]
        else:
            Rs = _proper_axis_rotations(np.asarray(desc.axes), sym)
        # A round shape has one rotation hypothesis; its section is tried at a few widths instead, since
        # a narrower section closer to the camera is a local minimum of the visible-arc fit.
        widths = _ROUND_WIDTHS if sym in ("y_continuous", "spherical") and up is not None else (1.0,)
        states = [_initial_state(pts, R, prior, up, plane, sym, w, cut_edge) for R in Rs for w in widths]

    # 3. optimise: coarse stage on all hypotheses, refinement of the best few
    total_iters = 0
    finals: list[tuple[_State, _Problem, int]]
    if warm:
        pb = problem(0, len(obs), cfg.warm_prior_points)
        st, _ = _optimise(pb, states[0], cfg.warm_iterations)
        total_iters += pb.iterations
        finals = [(st, pb, 0)]
    else:
        hyps = [(st, 0) for st in states]
        finals = []
        for k, stage in enumerate(cfg.stages):
            n_o = min(stage.obs_points, len(obs))
            ranked = []
            for st, ks in hyps:
                pb = problem(ks, n_o, stage.prior_points, k)
                it0 = pb.iterations
                st2, cost = _optimise(pb, st, stage.iterations)
                total_iters += pb.iterations - it0
                ranked.append((cost, st2, ks))
            if k == 0 and variants:
                # the mean shape's best rotation, with each articulation's own amodal initial box
                best_R = min(ranked, key=lambda r: r[0])[1].R
                for kv, shp in enumerate(variants, start=1):
                    pb = problem(kv, n_o, stage.prior_points, k)
                    it0 = pb.iterations
                    st0 = _initial_state(pts, best_R, shp, up, plane, sym, cut_edge=cut_edge)
                    st2, cost = _optimise(pb, st0, stage.iterations)
                    total_iters += pb.iterations - it0
                    ranked.append((cost, st2, kv))
            order = np.argsort([r[0] for r in ranked], kind="stable")
            last = k == len(cfg.stages) - 1
            keep = stage.keep + (len(variants) if k == 0 else 0)
            hyps = [(ranked[i][1], ranked[i][2]) for i in (order if last else order[:keep])]
            finals = [(st, problem(ks, n_o, stage.prior_points, k), ks) for st, ks in hyps]
    scored = []
    for st, pbx, ks in finals:
        cost, op, po, _, _ = _evaluate(pbx, st, False)
        scored.append((cost, op, po, st, pbx, ks))
    best = min(range(len(scored)), key=lambda i: scored[i][0])
    cost, op, po, st, pbx, k_best = scored[best]
    body_axis = round_body_axis(shapes[k_best]) if up is not None and cfg.handle_band_tol >= 0.0 else None
    if body_axis is not None and not warm:
        # a mug: the handle's yaw from its own points, or, hidden, the middle of the turns that hide it
        seen = protrusion_points(pbx.pose(st), body_axis, pts, cfg.handle_margin_m)
        seen = seen[:: max(1, len(seen) // 256)]  # at most 256 of them
        turned = None
        if len(seen) >= cfg.handle_sliver_points and cfg.handle_yaw_range_deg > 0.0:
            # The handle's own points set its yaw, searched all round the body: the fit's optimum can sit
            # a quarter turn off (the body's terms pull on it through the shared x scale of body and
            # handle). Fewer than `handle_min_points` (a handle seen edge-on, or stray edge points of a
            # hidden one) must match the prior's handle closely. Either way the turn must keep the loss
            # within the band that a hidden handle's turns span.
            prior_k = shapes[k_best]
            wide, match = _handle_yaw(pbx, st, body_axis, prior_k, seen, 180.0, cfg.handle_match_step_deg)
            sure = len(seen) >= cfg.handle_min_points or match <= cfg.handle_match_m**2
            ratio = _evaluate(pbx, wide, False)[0] / _evaluate(pbx, st, False)[0] if sure else math.inf
            log.debug("handle from %d points: match %.1f mm, loss ratio %.3f", len(seen),
                      1e3 * math.sqrt(match), ratio)  # fmt: skip
            if ratio <= 1.0 + cfg.handle_band_tol:
                turned = wide
            elif len(seen) >= cfg.handle_min_points:
                turned, _ = _handle_yaw(pbx, st, body_axis, prior_k, seen, cfg.handle_yaw_range_deg)
        if turned is None and len(seen) < cfg.handle_min_points:
            # a mug whose handle is hidden: the middle of the turns that hide it (FitConfig.handle_band_tol)
            turned = _middle_of_flat_band(pbx, st, body_axis, cfg)
        if turned is not None and turned is not st:
            st = turned
            cost, op, po, _, _ = _evaluate(pbx, st, False)
    fitted = pbx.pose(st)
    surface = seen_surface(fitted, plane, cfg, scene)
    pose = canonicalize_symmetry(grow_to_seen(fitted, sym, plane, cfg, scene, surface), sym, up)
    result = FitResult(
        pose=pose,
        loss=op + po,
        obs_to_prior=op,
        prior_to_obs=po,
        robust_loss=cost,
        hypotheses=len(states) if warm else len(Rs),
        hypothesis_losses=tuple(s[0] for s in scored),
        iterations=total_iters,
        n_points=len(obs),
        mode=mode,
        time_s=time.perf_counter() - t0,
        prior=shapes[k_best],
        coverage=math.nan if scene is None else mask_coverage(pose, shapes[k_best], scene),
        surface_points=surface if scene is not None else None,
    )
    log.debug("fit %s: loss %.3g m^2, %d hypotheses, %d iterations", prior.name, result.loss,
              result.hypotheses, result.iterations)  # fmt: skip
    return result
