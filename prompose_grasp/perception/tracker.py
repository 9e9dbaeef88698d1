"""Temporal refinement over a sliding window of frames (the paper's section 3.6, as a geometric tracker).

The first frame runs the whole estimator (grounding, prior, cold multi-hypothesis fit). Later frames are
cheap: the previous box, carried into the new camera frame (through `T_base_cam` when the frames carry it,
e.g. a wrist camera with the arm's forward kinematics; else the object is assumed still in the camera frame),
selects the depth points near it, and the fit is warm-started from it. Observations of the last `window`
frames are kept in the object frame and fused: each new frame's fit sees the union of the views, so the sides
seen earlier keep constraining the box and the anisotropic size becomes observable as the camera moves (the
paper's claim for its temporal window). The size of a rigid object does not change, so the reported size is
the median over the window; rotation and translation are blended with the prediction to suppress jitter.

The track is declared lost (and re-initialised by grounding) when too few points are found near the
prediction, or the fit's residual is large: the object left the view, was occluded, or was moved.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project, depth_to_point_map, farthest_point_sampling
from prompose_grasp.geometry.se3 import invert_T, so3_exp, so3_log
from prompose_grasp.perception.estimator import Estimate, plane_vector
from prompose_grasp.perception.fit import fit_pose
from prompose_grasp.perception.grounding import SupportPlane
from prompose_grasp.perception.priors import ShapePrior
from prompose_grasp.robot.interfaces import RGBDFrame

if TYPE_CHECKING:
    from prompose_grasp.perception.estimator import ProMPose

__all__ = ["Tracker", "TrackerConfig"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the tracker.

    Attributes:
        window: frames kept for fusion and smoothing (the paper's n = 16).
        roi_margin_m: observed points up to this far outside the predicted box belong to the object [m]; it
            must exceed the motion between frames that the prediction does not explain.
        plane_clearance_m: points this close to the support plane are the table, not the object [m]
            (the grounder's height cut, `GroundingConfig.min_height_m`).
        points_per_view: points kept of each frame for fusion (farthest point sampling).
        min_points: fewer points than this near the prediction means the track is lost.
        max_rms_m: a fit whose root-mean-square Chamfer residual exceeds this is a lost track [m]: a right
            fit leaves the sensor noise (a few mm at 1 m), a wrong one centimetres.
        blend: weight of the new measurement against the prediction for rotation and translation, in (0, 1];
            1 turns smoothing off.
    """

    window: int = 16
    roi_margin_m: float = 0.03
    plane_clearance_m: float = 0.008
    points_per_view: int = 256
    min_points: int = 50
    max_rms_m: float = 0.015
    blend: float = 0.6

    def __post_init__(self) -> None:
        if self.window < 1 or self.points_per_view < 8 or self.min_points < 4:
            raise InvalidInputError("TrackerConfig needs window >= 1, points_per_view >= 8, min_points >= 4")
        if not 0.0 < self.blend <= 1.0:
            raise InvalidInputError(f"TrackerConfig.blend must be in (0, 1], got {self.blend}")
        for name in ("roi_margin_m", "plane_clearance_m", "max_rms_m"):
            if not getattr(self, name) > 0:
                raise InvalidInputError(f"TrackerConfig.{name} must be > 0")


def _plane_in(plane: SupportPlane, T_new_old: np.ndarray) -> SupportPlane:
    """The same plane expressed in another camera frame (x_new = T_new_old x_old)."""
    n = T_new_old[:3, :3] @ plane.normal_cam
    return SupportPlane(n, plane.offset_m - float(n @ T_new_old[:3, 3]), plane.inlier_fraction)


def _blend(pred: Pose9D, meas: Pose9D, w: float, size: np.ndarray) -> Pose9D:
    """Geodesic blend of rotation and linear blend of translation; w = weight of `meas`."""
    R = pred.R @ so3_exp(w * so3_log(pred.R.T @ meas.R))
    return Pose9D(R, (1.0 - w) * pred.t + w * meas.t, size)


class Tracker:
    """Frame-to-frame 9-DoF tracking of one object named by a prompt. Use through `ProMPose.track`.

    The prior is generated once, on the first frame, and kept for the whole sequence.
    """

    def __init__(
        self,
        estimator: ProMPose,
        prompt: str,
        prior: ShapePrior | None = None,
        config: TrackerConfig | None = None,
    ):
        self.estimator = estimator
        self.prompt = prompt
        self.prior = prior
        self.config = config or TrackerConfig()
        self._views: deque[np.ndarray] = deque(maxlen=self.config.window)  # (k, 3) object-frame points
        self._sizes: deque[np.ndarray] = deque(maxlen=self.config.window)
        self._pose: Pose9D | None = None
        self._plane: SupportPlane | None = None
        self._T_base_cam: np.ndarray | None = None
        self._frame_index = 0
        self.reinitialisations = 0

    def update(self, frame: RGBDFrame) -> Estimate:
        """The estimate for the next frame of the sequence."""
        t_start = time.perf_counter()
        estimate = None if self._pose is None else self._track(frame)
        if estimate is None:
            estimate = self._initialise(frame)
        estimate.timings_ms["total"] = 1e3 * (time.perf_counter() - t_start)
        self._T_base_cam = frame.T_base_cam
        self._frame_index += 1
        return estimate

    # ------------------------------------------------------------------------------------------------------

    def _initialise(self, frame: RGBDFrame) -> Estimate:
        if self._pose is not None:
            self.reinitialisations += 1
            logger.info("track of %r lost at frame %d; re-grounding", self.prompt, self._frame_index)
        self._views.clear()
        self._sizes.clear()
        est = self.estimator.estimate(frame, self.prompt, prior=self.prior)
        self.prior = est.prior
        self._plane = est.support_plane
        self._accept(frame, est.pose, self._observed(frame, est.mask))
        return replace(est, timings_ms=dict(est.timings_ms), frame_index=self._frame_index)

    def _track(self, frame: RGBDFrame) -> Estimate | None:
        cfg = self.config
        t0 = time.perf_counter()
        T_new_old = np.eye(4)
        if frame.T_base_cam is not None and self._T_base_cam is not None:
            T_new_old = invert_T(frame.T_base_cam) @ self._T_base_cam
        assert self._pose is not None
        pred = self._pose.transformed(T_new_old)
        plane = None if self._plane is None else _plane_in(self._plane, T_new_old)
        mask, points = self._select(frame, pred, plane)
        if len(points) < cfg.min_points:
            return None
        # Fuse: the views of the window, carried into this frame by the prediction, plus this frame's points.
        fused = [points]
        fused.extend(view @ pred.R.T + pred.t for view in self._views)
        fit = fit_pose(
            np.concatenate(fused),
            self.prior,
            self.estimator.fit_config,
            init=pred,
            support_plane_cam=plane_vector(plane),
        )
        if not math.isfinite(fit.loss) or math.sqrt(max(fit.loss, 0.0) / 2.0) > cfg.max_rms_m:
            return None
        self._plane = plane
        size = np.median(np.stack([*self._sizes, fit.pose.size]), axis=0)
        pose = _blend(pred, fit.pose, cfg.blend, size)
        self._accept(frame, pose, points)
        pose_ms = 1e3 * (time.perf_counter() - t0)
        ys, xs = np.nonzero(mask)
        return Estimate(
            pose=pose,
            mask=mask,
            box_xyxy=np.array([xs.min(), ys.min(), xs.max(), ys.max()]),
            score=float("nan"),
            prior=self.prior,
            fit_loss=float(fit.loss),
            timings_ms={"grounding": 0.0, "prior": 0.0, "pose": pose_ms},
            frame_index=self._frame_index,
            support_plane=plane,
        )

    def _accept(self, frame: RGBDFrame, pose: Pose9D, points_cam: np.ndarray) -> None:
        """Remember this frame's pose and its points (in the object frame) for the next frames."""
        if len(points_cam) > self.config.points_per_view:
            points_cam = points_cam[farthest_point_sampling(points_cam, self.config.points_per_view)]
        self._views.append(pose.points_to_object(points_cam))
        self._sizes.append(np.asarray(pose.size))
        self._pose = pose

    def _observed(self, frame: RGBDFrame, mask: np.ndarray) -> np.ndarray:
        return back_project(frame.depth_m, frame.intrinsics, mask=mask)

    def _select(
        self, frame: RGBDFrame, pred: Pose9D, plane: SupportPlane | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (H, W) bool and their (N, 3) points lying in the predicted box grown by the margin, off the
        support plane. Only the image rectangle of the grown box is back-projected."""
        K = frame.intrinsics
        grown = Pose9D(pred.R, pred.t, pred.size + 2.0 * self.config.roi_margin_m)
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
        sub = depth_to_point_map(frame.depth_m[y0 : y1 + 1, x0 : x1 + 1], crop)
        keep = np.all(np.isfinite(sub), axis=2)
        pts = sub[keep]
        inside = grown.contains(pts)
        if plane is not None:
            inside &= plane.height_m(pts) > self.config.plane_clearance_m
        rows, cols = np.nonzero(keep)
        mask[rows[inside] + y0, cols[inside] + x0] = True
        return mask, pts[inside]
