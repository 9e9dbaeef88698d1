"""Temporal refinement over a sliding window of frames (the paper's section 3.6, as a geometric tracker).

The first frame runs the whole estimator (grounding, or the caller's mask; prior; cold multi-hypothesis fit).
Later frames are cheap: the previous box, carried into the new camera frame (through `T_base_cam` when the
frames carry it, e.g. a wrist camera with the arm's forward kinematics; else the object is assumed still in
the camera frame), selects the depth points near it (inside the grown box and near the posed prior's surface,
so a neighbour touching the box is left out), and the fit is warm-started from it.

Fusion: the points of the last `window` frames are kept and each new frame's fit sees their union, so the
sides seen earlier keep constraining the box and the amodal size becomes observable as the camera moves (the
paper's claim for its temporal window). The fused fit takes this frame's camera view (`SceneView` of the
selected pixels), as the first frame's fit did: prior points this camera could not have seen (beyond the
image border, behind an occluder) do not pull, while every view's points pull the prior towards them. With
`T_base_cam` the views are kept in the base frame: the object is taken as still in the world, so the fused
cloud is independent of the poses estimated on the way (views kept in the object frame follow the estimate
that placed them: an error of the first frame is baked into every later view and the fused cloud then
confirms it). Without `T_base_cam` the object frame is the only common frame. The size of a rigid object
does not change: it is smoothed in log space like translation and rotation.

Re-fits: when the view has turned, a mug's handle shows that the track does not explain, or the selection
runs out of the tracked box (the object is larger than the track: its first view was cut), the frame also
gets a cold fit, and the better of the two by `Tracker._score` goes on. That cold fit sees the object as the
grounder segments this frame: the candidate for the prompt that holds most of the tracked selection
(`Tracker._redetected`), so all of the object, none of a neighbour beside it.

The current frame's own points decide whether the fused fit holds: their RMS distance to the fitted prior
surface above `max_rms_m` means the object moved against the world (then the current frame alone is fitted
and the window restarts from it) or the track is lost (too few points near the prediction, or the single-frame
fit is bad too): then the object is grounded again.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.errors import InvalidInputError, PromposeError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import outline_corrected_points, valid_depth_mask
from prompose_grasp.geometry.se3 import invert_T, so3_exp, so3_log
from prompose_grasp.perception.estimate import Estimate, plane_vector
from prompose_grasp.perception.fit import FitConfig, FitResult, SceneView, fit_pose, protrusion_points
from prompose_grasp.perception.grounding import Grounder, SupportPlane
from prompose_grasp.perception.priors import ShapePrior
from prompose_grasp.perception.priors.library import round_body_axis
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["Tracker", "TrackerConfig"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the tracker.

    Attributes:
        window: frames kept for fusion and smoothing (the paper's n = 16).
        roi_margin_m: observed points up to this far outside the predicted box belong to the object [m]; it
            must exceed the motion between frames that the prediction does not explain.
        surface_margin_m: of those, only points within this distance of the posed prior's surface are kept
            [m] (a neighbouring object inside the grown box is not this object's surface).
        plane_clearance_m: points this close to the support plane are the table, not the object [m]
            (the grounder's height cut, `GroundingConfig.min_height_m`).
        points_per_view: points kept of each frame for fusion (a seeded random subset).
        min_points: fewer points than this near the prediction means the track is lost.
        max_rms_m: a fit whose root-mean-square Chamfer residual exceeds this is a lost track [m]: a right
            fit leaves the sensor noise (a few mm at 1 m), a wrong one centimetres.
        blend: weight of the new measurement against the prediction for rotation, translation and log size,
            in (0, 1]; 1 turns smoothing off.
        refit_angle_deg: when the direction from the object to the camera has turned by more than this since
            the last re-fit, the frame gets a cold multi-hypothesis fit too (`Tracker._refit`), and the better
            of it and the tracked fit (`Tracker._score`) goes on: a wrong first estimate (a mug's yaw
            with the handle hidden, a flipped box seen edge-on) is corrected once the new views
            show what the first did not, and a laptop's screen opening is chosen again. A mug's handle that
            the track does not explain starts one too, once per view (`Tracker._protrusion_missed`: a camera
            that holds still never turns), and so does a selection that runs out of the tracked box
            (`outgrown_margin_m`). 180 turns all re-fits off (a warm start cannot jump between basins).
        compare_points: observed points of this frame on which the two candidates are compared.
        refit_gain: the re-fit replaces the tracked fit when its score is below this times the tracked
            one's (hysteresis: the tracked fit has the window's views behind it).
        old_view_weight: weight of the earlier views' term in that score.
        pixel_stride: every k-th pixel of the predicted box's image rectangle is back-projected on tracked
            frames (the warm fit uses a few hundred points; the mask marks each sampled pixel's k x k block).
        prior_points: prior surface samples (an even stride) used to select points near the posed prior and
            to measure the residual.
        fit_iterations: Gauss-Newton iterations of a tracked frame's warm fit (the prediction is close).
        fit_points, fit_prior_points: observed (of the fused cloud) and prior points of that warm fit.
        outgrown_margin_m, outgrown_share: a frame whose selected points lie outside the tracked box by more
            than the margin [m] (beyond the depth noise at the faces), at least this share of them, gets a
            re-fit too (`Tracker._outgrown`, once per view): the object is larger than the track, which grows
            only by the selection's `roi_margin_m` a frame otherwise.
        redetect_share: a re-fit fits the grounder's candidate for the prompt holding more than this share of
            the tracked selection (`Tracker._redetected`), when there is one: the whole object, segmented.
            1 turns re-detection off.
    """

    window: int = 16
    roi_margin_m: float = 0.03
    surface_margin_m: float = 0.02
    plane_clearance_m: float = 0.008
    points_per_view: int = 512
    min_points: int = 50
    max_rms_m: float = 0.015
    blend: float = 0.6
    refit_angle_deg: float = 20.0
    compare_points: int = 1024
    refit_gain: float = 1.0
    old_view_weight: float = 1.0
    pixel_stride: int = 2
    prior_points: int = 1024
    fit_iterations: int = 8
    fit_points: int = 384
    fit_prior_points: int = 512
    outgrown_margin_m: float = 0.01
    outgrown_share: float = 0.05
    redetect_share: float = 0.5

    def __post_init__(self) -> None:
        if self.window < 1 or self.points_per_view < 8 or self.min_points < 4:
            raise InvalidInputError("TrackerConfig needs window >= 1, points_per_view >= 8, min_points >= 4")
        if self.fit_points < 8 or self.fit_prior_points < 8:
            raise InvalidInputError("TrackerConfig needs fit_points >= 8 and fit_prior_points >= 8")
        if self.pixel_stride < 1 or self.prior_points < 8 or self.fit_iterations < 0:
            raise InvalidInputError(
                "TrackerConfig needs pixel_stride >= 1, prior_points >= 8 and fit_iterations >= 0"
            )
        if not 0.0 < self.refit_angle_deg <= 180.0 or self.compare_points < 8:
            raise InvalidInputError("TrackerConfig needs 0 < refit_angle_deg <= 180 and compare_points >= 8")
        if not 0.0 < self.blend <= 1.0:
            raise InvalidInputError(f"TrackerConfig.blend must be in (0, 1], got {self.blend}")
        margins = ("roi_margin_m", "surface_margin_m", "plane_clearance_m", "max_rms_m", "outgrown_margin_m")
        for name in margins:
            if not getattr(self, name) > 0:
                raise InvalidInputError(f"TrackerConfig.{name} must be > 0")
        for name in ("outgrown_share", "redetect_share"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise InvalidInputError(f"TrackerConfig.{name} must be in (0, 1], got {getattr(self, name)}")


def _plane_in(plane: SupportPlane, T_new_old: np.ndarray) -> SupportPlane:
    """The same plane expressed in another camera frame (x_new = T_new_old x_old)."""
    n = T_new_old[:3, :3] @ plane.normal_cam
    return SupportPlane(n, plane.offset_m - float(n @ T_new_old[:3, 3]), plane.inlier_fraction)


def _blend(pred: Pose9D, meas: Pose9D, w: float) -> Pose9D:
    """Geodesic blend of rotation, linear blend of translation and of log size; w = weight of `meas`."""
    R = pred.R @ so3_exp(w * so3_log(pred.R.T @ meas.R))
    size = np.exp((1.0 - w) * np.log(pred.size) + w * np.log(meas.size))
    return Pose9D(R, (1.0 - w) * pred.t + w * meas.t, size)


class FrameEstimator(Protocol):
    """What the tracker asks of the single-frame estimator (`ProMPose` is one): a (re)started track's
    estimate, the fit settings the windowed re-fits share, the grounder for re-detection, the size bound of
    an object and the object's points under a mask. Given explicitly so that the tracker does not import the
    facade that builds it."""

    grounder: Grounder
    fit_config: FitConfig

    def estimate(
        self, frame: RGBDFrame, prompt: str, prior: ShapePrior | None = None, mask: np.ndarray | None = None
    ) -> Estimate: ...

    def too_large(self, pose: Pose9D) -> bool: ...

    def object_points(self, frame: RGBDFrame, mask: np.ndarray) -> np.ndarray: ...


class Tracker:
    """Frame-to-frame 9-DoF tracking of one object named by a prompt. Use through `ProMPose.track`.

    The prior is generated once, on the first frame, and kept for the whole sequence.
    """

    def __init__(
        self,
        estimator: FrameEstimator,
        prompt: str,
        prior: ShapePrior | None = None,
        config: TrackerConfig | None = None,
    ):
        self.estimator = estimator
        self.prompt = prompt
        self.prior = prior
        self.config = config or TrackerConfig()
        # (k, 3) points of each view in the base frame (`_in_base`) or else in the object frame [m]
        self._views: deque[np.ndarray] = deque(maxlen=self.config.window)
        self._in_base = False
        self._pose: Pose9D | None = None
        self._plane: SupportPlane | None = None
        self._T_base_cam: np.ndarray | None = None
        self._frame_index = 0
        self._rng = np.random.default_rng(0)
        self._prior_cache: tuple[ShapePrior, np.ndarray] | None = None
        self._refit_view: np.ndarray | None = None  # unit object -> camera direction at the last re-fit
        # a re-fit without a turn (for an unexplained handle or an outgrown box) ran at this view
        self._unturned_refit_done = False
        # the score of the grounding that (re)started the track, carried by its tracked updates
        self._grounding_score = math.nan
        self.reinitialisations = 0
        self.window_restarts = 0
        self.refits = 0
        self.refits_taken = 0

    def update(self, frame: RGBDFrame, mask: np.ndarray | None = None) -> Estimate:
        """The estimate for the next frame of the sequence.

        `mask`: (H, W) bool pixels of the object in this frame (your own segmentation); when given, the track
        (re)starts from it instead of grounding the prompt.

        The estimate of a (re)started track is the estimator's own (`ProMPose.estimate`). A tracked update
        has the same fields with these meanings: `score` is the grounding score of the estimate that
        (re)started the track, carried unchanged (1 when that was a mask handed in); `fit_loss` is the
        warm fit's L_geo over the window's fused points; `coverage` and `probability` are NaN and
        `contenders` is -1 (not judged: the frame was not grounded). A tracked box longer than
        `EstimatorConfig.max_object_size_m` counts as a lost track.
        """
        t_start = time.perf_counter()
        estimate = None if (self._pose is None or mask is not None) else self._track(frame)
        if estimate is None:
            estimate = self._initialise(frame, mask)
        estimate.timings_ms["total"] = 1e3 * (time.perf_counter() - t_start)
        self._T_base_cam = frame.T_base_cam
        self._frame_index += 1
        return estimate

    # ------------------------------------------------------------------------------------------------------

    def _initialise(self, frame: RGBDFrame, mask: np.ndarray | None = None) -> Estimate:
        if self._pose is not None and mask is None:
            self.reinitialisations += 1
            logger.info("track of %r lost at frame %d; re-grounding", self.prompt, self._frame_index)
        self._views.clear()
        est = self.estimator.estimate(frame, self.prompt, prior=self.prior, mask=mask)
        self.prior = est.prior
        self._grounding_score = float(est.score)
        self._plane = est.support_plane
        self._in_base = frame.T_base_cam is not None
        self._refit_view = self._view_direction(frame, est.pose)
        self._unturned_refit_done = False
        self._accept(frame, est.pose, self._observed(frame, est.mask))
        return replace(est, timings_ms=dict(est.timings_ms), frame_index=self._frame_index)

    def _track(self, frame: RGBDFrame) -> Estimate | None:
        cfg = self.config
        t0 = time.perf_counter()
        T_new_old = np.eye(4)
        if frame.T_base_cam is not None and self._T_base_cam is not None:
            T_new_old = invert_T(frame.T_base_cam) @ self._T_base_cam
        elif self._in_base:  # the camera pose stopped coming: the base-frame views cannot be carried over
            self._views.clear()
            self._in_base = False
        assert self._pose is not None and self.prior is not None
        pred = self._pose.transformed(T_new_old)
        plane = None if self._plane is None else _plane_in(self._plane, T_new_old)
        mask, points = self._select(frame, pred, plane)
        if len(points) < cfg.min_points:
            return None
        current = self._thin(points)
        fit_config = replace(
            self.estimator.fit_config,
            warm_iterations=cfg.fit_iterations,
            n_points_warm=cfg.fit_points,
            warm_prior_points=cfg.fit_prior_points,
        )
        support = plane_vector(plane)
        old_views = np.concatenate([np.zeros((0, 3)), *self._fused_views(frame, pred)])
        cloud = np.concatenate([current, old_views])
        # this camera's view: the prior points it could not have seen (off the image, behind an occluder) do
        # not pull; the earlier views' points still pull the prior towards them
        seen = SceneView(frame.depth_m, frame.intrinsics, mask)
        fit = fit_pose(cloud, self.prior, fit_config, init=pred, support_plane_cam=support, scene=seen)
        # this frame's RMS to the fit, for the checks below; NaN when the fit changes and it must be redone
        rms = self._rms(current, fit.pose) if self._views else math.nan
        if rms > cfg.max_rms_m:
            # the window disagrees with this frame: the object moved in the world; start the window again
            cloud, old_views = current, np.zeros((0, 3))
            fit = fit_pose(current, self.prior, fit_config, init=pred, support_plane_cam=support, scene=seen)
            rms = math.nan
            self._views.clear()
            self.window_restarts += 1
        jumped, grounding_ms = False, 0.0
        view = self._view_direction(frame, fit.pose)
        turned = self._refit_view is not None and float(view @ self._refit_view) < math.cos(
            math.radians(cfg.refit_angle_deg)
        )
        outgrown = self._outgrown(current, pred)
        if turned or outgrown or self._protrusion_missed(frame, pred, plane):
            self._refit_view = view
            self._unturned_refit_done = not turned
            self.refits += 1
            # the re-fit sees this frame as the first frame's fit did: every pixel, and round a mug's body
            # wherever its handle is (near the tracked pose's surface only, a handle that the track has
            # on the wrong side would be cut away, the very points that can correct it)
            refit_mask, refit_points = self._select(frame, pred, plane, stride=1, any_turn=True)
            if len(refit_points) < cfg.min_points:
                refit_mask, refit_points = mask, points
            # better still, the object as the grounder segments this frame: all of it (the selection ends a
            # few cm past the tracked box) and none of a neighbour the handle's circle reaches
            detected, grounding_ms = self._redetected(frame, refit_mask)
            if detected is not None:
                refit_mask, refit_points = detected, self._observed(frame, detected)
            scene = SceneView(frame.depth_m, frame.intrinsics, refit_mask)
            cold = self._refit(refit_points, support, scene)
            if self._score(refit_points, old_views, cold, support, scene) < cfg.refit_gain * self._score(
                refit_points, old_views, fit, support, scene
            ):
                fit, jumped, rms = cold, True, math.nan
                self.prior = cold.prior or self.prior
                self.refits_taken += 1
        if math.isnan(rms):
            rms = self._rms(current, fit.pose)
        if not math.isfinite(fit.loss) or rms > cfg.max_rms_m or self.estimator.too_large(fit.pose):
            return None
        self._plane = plane
        # a jump to another basin is not smoothed (half-way between two yaws is neither)
        pose = fit.pose if jumped else _blend(pred, fit.pose, cfg.blend)
        self._accept(frame, pose, current)
        pose_ms = 1e3 * (time.perf_counter() - t0) - grounding_ms  # the re-detection is grounding
        ys, xs = np.nonzero(mask)
        return Estimate(
            pose=pose,
            mask=mask,
            box_xyxy=np.array([xs.min(), ys.min(), xs.max(), ys.max()]),
            score=self._grounding_score,
            prior=self.prior,
            fit_loss=float(fit.loss),
            timings_ms={"grounding": grounding_ms, "prior": 0.0, "pose": pose_ms},
            frame_index=self._frame_index,
            support_plane=plane,
            surface_cam=fit.surface_points,
        )

    def _protrusion_missed(self, frame: RGBDFrame, pred: Pose9D, plane: SupportPlane | None) -> bool:
        """True when this frame shows a round body's protrusion (a mug's handle) that the prediction does
        not explain: at least `FitConfig.handle_min_points` pixels lie near the prior turned about the
        body's axis, outside the predicted body by `FitConfig.handle_margin_m`, and farther than
        `surface_margin_m` from the predicted surface. Once per view (cleared when the view turns)."""
        if self._unturned_refit_done or self.prior is None or self.config.refit_angle_deg >= 180.0:
            return False  # (re-fits off: `refit_angle_deg` 180)
        axis = round_body_axis(self.prior)
        if axis is None:
            return False
        _, swept = self._select(frame, pred, plane, any_turn=True)
        fcfg = self.estimator.fit_config
        stride2 = self.config.pixel_stride**2
        outside = protrusion_points(pred, axis, swept, fcfg.handle_margin_m)
        if len(outside) * stride2 < fcfg.handle_min_points:
            return False
        d, _ = cKDTree(pred.points_to_camera(self._prior_sample())).query(
            outside, k=1, distance_upper_bound=self.config.surface_margin_m
        )
        missed = int(np.count_nonzero(~np.isfinite(d))) * stride2
        return missed >= fcfg.handle_min_points

    def _outgrown(self, points_cam: np.ndarray, pred: Pose9D) -> bool:
        """True when at least `outgrown_share` of this frame's selected points lie outside the predicted box
        by more than `outgrown_margin_m`: the object goes on past the box (a track started on a view that
        the image border or an occluder cut; the selection reaches only `roi_margin_m` past the box). Once
        per view, as `_protrusion_missed` (a re-fit that did not win would be run again every frame)."""
        if self._unturned_refit_done or self.config.refit_angle_deg >= 180.0:
            return False  # (re-fits off: `refit_angle_deg` 180)
        local = np.abs((points_cam - pred.t) @ pred.R) - 0.5 * pred.size
        outside = np.any(local > self.config.outgrown_margin_m, axis=1)
        return bool(np.count_nonzero(outside) >= self.config.outgrown_share * len(points_cam))

    def _redetected(self, frame: RGBDFrame, selection: np.ndarray) -> tuple[np.ndarray | None, float]:
        """The mask of the grounder's candidate for the prompt that holds most of `selection` (the tracked
        pixels, (H, W) bool), when it holds more than `redetect_share` of them, else None (no candidate, or
        the grounder cannot score this prompt); and the grounding's time [ms] (0 when it did not run)."""
        n = int(np.count_nonzero(selection))
        if n == 0 or self.config.redetect_share >= 1.0:
            return None, 0.0
        t0 = time.perf_counter()
        try:
            grounding = self.estimator.grounder.ground(
                frame.rgb, frame.depth_m, frame.intrinsics, self.prompt
            )
        except PromposeError as exc:
            logger.info("re-detection of %r skipped: %s", self.prompt, exc)
            return None, 1e3 * (time.perf_counter() - t0)
        grounding_ms = 1e3 * (time.perf_counter() - t0)
        best, best_share = None, self.config.redetect_share
        for candidate in grounding.candidates:
            share = np.count_nonzero(candidate.mask & selection) / n
            if share > best_share:
                best, best_share = candidate.mask, share
        return (None if best is None else np.asarray(best, dtype=bool)), grounding_ms

    def _refit(self, points: np.ndarray, support: np.ndarray | None, scene: SceneView | None) -> FitResult:
        """A cold multi-hypothesis fit of this frame's points (the estimator's own fit settings, and the
        frame's depth image and selection as its `SceneView`, as the first frame's fit had).

        Tried and measured (docs/fit.md, temporal refinement): a warm fit of the frame alone from the
        tracked pose and its quarter turns costs a third of this and lost ~5 points on the benchmark's
        tracked rows; the cold fit without its 2048-point stage saved no measurable time.
        """
        assert self.prior is not None
        return fit_pose(points, self.prior, self.estimator.fit_config, support_plane_cam=support, scene=scene)

    def _fused_views(self, frame: RGBDFrame, pred: Pose9D) -> list[np.ndarray]:
        """The window's views in this camera frame."""
        if self._in_base:
            assert frame.T_base_cam is not None  # views are kept in the base frame only with a camera pose
            T = invert_T(frame.T_base_cam)
            return [v @ T[:3, :3].T + T[:3, 3] for v in self._views]
        return [v @ pred.R.T + pred.t for v in self._views]

    def _view_direction(self, frame: RGBDFrame, pose: Pose9D) -> np.ndarray:
        """Unit direction from the object to the camera, in the base frame when known (else object frame)."""
        d = -pose.t / max(float(np.linalg.norm(pose.t)), 1e-9)
        if frame.T_base_cam is not None:
            return frame.T_base_cam[:3, :3] @ d
        return pose.R.T @ d

    def _score(
        self,
        points: np.ndarray,
        old_views: np.ndarray,
        fit: FitResult,
        support: np.ndarray | None,
        scene: SceneView | None = None,
    ) -> float:
        """How well a fitted pose explains the window: the robust L_geo of this frame's points (both
        directions, this camera's visibility; no iterations) plus the Huber mean distance of the earlier
        views' points to the posed prior (one direction: which prior points those cameras saw is not
        modelled, but every observed point lies on the object's surface)."""
        cfg = replace(self.estimator.fit_config, n_points_warm=self.config.compare_points, warm_iterations=0)
        prior = fit.prior or self.prior
        assert prior is not None
        fitted = fit_pose(points, prior, cfg, init=fit.pose, support_plane_cam=support, scene=scene)
        score = fitted.robust_loss
        if len(old_views):
            surface = fit.pose.points_to_camera(prior.points[:: max(1, len(prior.points) // 2048)])
            d, _ = cKDTree(surface).query(old_views, k=1)
            h = cfg.huber_m
            huber = np.where(d <= h, d * d, 2.0 * h * d - h * h)
            score += self.config.old_view_weight * float(np.mean(huber))
        return score

    def _rms(self, points_cam: np.ndarray, pose: Pose9D) -> float:
        """Root-mean-square distance of the points to the posed prior's surface samples [m]."""
        assert self.prior is not None
        d, _ = cKDTree(pose.points_to_camera(self._prior_sample())).query(points_cam, k=1)
        return float(np.sqrt(np.mean(d * d)))

    def _prior_sample(self) -> np.ndarray:
        """At most `prior_points` of the prior's surface samples (unit box), an even stride, cached."""
        assert self.prior is not None
        if self._prior_cache is None or self._prior_cache[0] is not self.prior:
            pts = np.asarray(self.prior.points)
            step = max(1, len(pts) // self.config.prior_points)
            self._prior_cache = (self.prior, pts[::step])
        return self._prior_cache[1]

    def _thin(self, points_cam: np.ndarray) -> np.ndarray:
        n = self.config.points_per_view
        if len(points_cam) <= n:
            return points_cam
        return points_cam[self._rng.choice(len(points_cam), n, replace=False)]

    def _accept(self, frame: RGBDFrame, pose: Pose9D, points_cam: np.ndarray) -> None:
        """Remember this frame's pose and its points (in the base or object frame) for the next frames."""
        points_cam = self._thin(points_cam)
        if self._in_base:
            T = frame.T_base_cam
            assert T is not None
            self._views.append(points_cam @ T[:3, :3].T + T[:3, 3])
        else:
            self._views.append(pose.points_to_object(points_cam))
        self._pose = pose

    def _observed(self, frame: RGBDFrame, mask: np.ndarray) -> np.ndarray:
        return self.estimator.object_points(frame, mask)

    def _select(
        self,
        frame: RGBDFrame,
        pred: Pose9D,
        plane: SupportPlane | None,
        stride: int | None = None,
        any_turn: bool = False,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (H, W) bool and their (N, 3) points lying in the predicted box grown by the margin, off the
        support plane, near the posed prior's surface. Only the image rectangle of the grown box is
        back-projected, every `stride`-th pixel (default `TrackerConfig.pixel_stride`).

        `any_turn`: for a prior with a round body (`priors.library.round_body_axis`: a mug), the points the
        prior explains at any turn about the body's axis, wherever its handle is: the box is widened to the
        circle the handle sweeps, and the surface test compares (distance from the axis, height) with the
        prior's own. A track with the handle on the wrong side keeps the handle's points this way.
        """
        K = frame.intrinsics
        margin = self.config.roi_margin_m
        axis = round_body_axis(self.prior) if any_turn and self.prior is not None else None
        box, axis_obj, profile = pred, np.zeros(3), None
        if axis is not None:
            axis_obj = np.array([axis[0] * pred.size[0], 0.0, axis[1] * pred.size[2]])  # object frame [m]
            metric = self._prior_sample() * pred.size
            profile = np.column_stack(
                [np.hypot(metric[:, 0] - axis_obj[0], metric[:, 2] - axis_obj[2]), metric[:, 1]]
            )
            reach = float(profile[:, 0].max())
            box = Pose9D(pred.R, pred.t + pred.R @ axis_obj, np.array([2 * reach, pred.size[1], 2 * reach]))
        grown = Pose9D(box.R, box.t, box.size + 2.0 * margin)
        corners = grown.corners()
        mask = np.zeros((K.height, K.width), dtype=bool)
        if np.any(corners[:, 2] <= 1e-3):
            return mask, np.zeros((0, 3))
        uv = K.project(corners)
        x0, y0 = np.floor(uv.min(axis=0)).astype(int)
        x1, y1 = np.ceil(uv.max(axis=0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, K.width - 1), min(y1, K.height - 1)
        if x0 > x1 or y0 > y1:
            return mask, np.zeros((0, 3))
        # The crop's own camera: the same focal lengths, the principal point shifted by the crop's corner.
        crop = CameraIntrinsics(K.fx, K.fy, K.cx - x0, K.cy - y0, width=x1 - x0 + 1, height=y1 - y0 + 1)
        k = self.config.pixel_stride if stride is None else stride
        if k > 1:  # every k-th pixel: the crop's camera with focal lengths and principal point divided by k
            w, h = math.ceil(crop.width / k), math.ceil(crop.height / k)
            crop = CameraIntrinsics(crop.fx / k, crop.fy / k, crop.cx / k, crop.cy / k, width=w, height=h)
        # `depth_to_point_map` of the crop, back-projecting only the pixels with a reading (the same
        # arithmetic: x = z (u - cx) / fx per pixel, in row-major order)
        sub = frame.depth_m[y0 : y1 + 1 : k, x0 : x1 + 1 : k]
        rows, cols = np.nonzero(valid_depth_mask(sub))
        z = sub[rows, cols].astype(np.float64)
        u = (np.arange(crop.width) - crop.cx) / crop.fx
        v = (np.arange(crop.height) - crop.cy) / crop.fy
        pts = np.column_stack([z * u[cols], z * v[rows], z])
        # `grown.contains(pts)`, without its input checks (the points are finite by construction)
        inside = np.all(np.abs((pts - grown.t) @ grown.R) <= 0.5 * grown.size, axis=1)
        if plane is not None:
            inside &= plane.height_m(pts) > self.config.plane_clearance_m
        if self.prior is not None and np.any(inside):
            idx = np.flatnonzero(inside)
            if profile is None:
                surface = cKDTree(pred.points_to_camera(self._prior_sample()))
                d, _ = surface.query(pts[idx], k=1, distance_upper_bound=self.config.surface_margin_m)
            else:
                local = (pts[idx] - pred.t) @ pred.R - axis_obj
                q = np.column_stack([np.hypot(local[:, 0], local[:, 2]), local[:, 1]])
                d, _ = cKDTree(profile).query(q, k=1, distance_upper_bound=self.config.surface_margin_m)
            inside[idx[~np.isfinite(d)]] = False
        picked = np.zeros(sub.shape, dtype=bool)
        picked[rows[inside], cols[inside]] = True
        # the points as the first frame's fit saw them: the free outline half a sample out
        # (`ProMPose.object_points`); the same pixels in the same row-major order
        points = outline_corrected_points(sub, crop, picked, self.estimator.fit_config.occlusion_margin_m)
        # each sampled pixel stands for its k x k block (cut at the crop's edge)
        if k > 1:
            picked = np.repeat(np.repeat(picked, k, axis=0), k, axis=1)
        mask[y0 : y1 + 1, x0 : x1 + 1] = picked[: y1 - y0 + 1, : x1 - x0 + 1]
        return mask, points
