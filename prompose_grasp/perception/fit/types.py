"""The fit's settings and result: `FitStage`, `FitConfig`, `FitResult` (docs/fit.md has the reasons for each
default)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.priors.prior import ShapePrior

__all__ = ["FitConfig", "FitResult", "FitStage"]


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
        free_section_ratio: a body of revolution's fit (a `y_continuous` prior standing upright) is tried
            again with two section widths (`core._free_section`, judged on the next-to-last stage's clouds)
            and the elliptical section is kept when its loss is under this share of the round one's (0
            switches the trial off). A family chosen from the words ("bottle") may be round where the object
            is flattened (a squeeze bottle: 5.8 of 9.5 cm, 61 %) or a can oval. Measured on oracle masks:
            round cans, bottles, cups, bowls and glasses of the generated tabletop and look-alike scenes and
            the real meshes (51 objects) keep 0.84-0.99 (the extra width fits some noise); synthetic
            flattened cans and bottles (`test_fit.py`'s views, 6 each) reach 0.34-0.71 at 55 % of their
            width, where the round fit's mean IoU is 0.57-0.58 and the free one's 0.87-0.91; at 70 % cans
            reach 0.60-0.75 and switch, bottles 0.80-0.89 and stay round (IoU 0.67). The free fit leaves out
            the family's prior on the section's aspect (`aspect_weight` on x:z), which is what it frees. It
            adds ~30 ms to the first frame of a round object (2 cores).
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
    free_section_ratio: float = 0.8
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
        r = self.free_section_ratio
        if not (isinstance(r, int | float) and not isinstance(r, bool) and 0.0 <= r <= 1.0):
            raise InvalidInputError(f"FitConfig.free_section_ratio must be in [0, 1], got {r!r}")


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
