"""Observe: capture frames the loop can trust and estimate the prompt on them.

Every captured frame first loses the depth readings that lie on the robot itself (its capsules at the joints
of the capture, `PickConfig.self_filter_margin_m`) and on the cell's bins (their floors and walls,
`grasp.bins.without_bins`), so neither a link in view nor the tote is offered as an object. A frame
whose image size or intrinsics differ from its camera's first frame of the run is captured again (the
hand-eye calibration and the depth registration hold for one mode).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import AmbiguousObjectError, CameraError, InvalidInputError, ObjectNotFoundError
from prompose_grasp.geometry.se3 import transform_points
from prompose_grasp.grasp import ObjectModel, Plane
from prompose_grasp.grasp.bins import without_bins
from prompose_grasp.grasp.self_filter import without_robot as robot_free_frame
from prompose_grasp.pipeline.describe import describe_contenders
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.seams import ObjectEstimate
from prompose_grasp.robot.interfaces import RGBDCamera, RGBDFrame

__all__ = ["FrameCheck", "Observation", "capture", "estimates", "estimates_once", "to_base"]

logger = logging.getLogger(__name__)

#: The raw frame -> why it cannot be trusted, or None.
FrameCheck = Callable[[RGBDFrame], "str | None"]


@dataclass(frozen=True, eq=False)
class Observation:
    """One observation of the target: the frame, the estimate chosen, the target in `base`, the support
    plane, the observed points in `base` (N, 3) [m], and the joints (6,) [rad] at the capture."""

    frame: RGBDFrame
    estimate: ObjectEstimate
    target: ObjectModel
    support: Plane | None
    points_base: np.ndarray
    q_seen: np.ndarray


def _mode_text(mode: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in mode) + ")"


def capture(loop: Loop, run: RunRecord, camera: RGBDCamera, check: FrameCheck | None = None) -> RGBDFrame:
    """The next frame of `camera` the loop can trust, without the robot's own depth readings. A dropped
    frame, one whose image size or intrinsics differ from this camera's first frame of the run (a camera
    that changed mode mid-run), and one that `check` refuses are retried `camera_retries` times in all, then
    "camera_failed"."""
    errors = []
    for _ in range(loop.config.camera_retries):
        try:
            frame = camera.capture()
        except CameraError as exc:  # a dropped frame: try again
            errors.append(str(exc))
            logger.warning("camera capture failed (%s); retrying", exc)
            continue
        if not isinstance(frame, RGBDFrame):
            raise Abort("camera_failed", f"the camera returned {type(frame).__name__}, not an RGBDFrame")
        if frame.T_base_cam is None:
            raise Abort("camera_failed", "the frame has no T_base_cam: calibrate the camera to the base")
        K = frame.intrinsics
        mode = (float(K.width), float(K.height), K.fx, K.fy, K.cx, K.cy)
        first = run.camera_modes.setdefault(id(camera), mode)
        why = None
        if mode != first:
            why = (
                f"the camera's image size and intrinsics changed mid-run (w, h, fx, fy, cx, cy "
                f"{_mode_text(first)} -> {_mode_text(mode)})"
            )
        elif check is not None:
            why = check(frame)
        if why is not None:
            errors.append(why)
            logger.warning("frame not trusted (%s); capturing again", why)
            continue
        run.last_raw_frame = frame
        seen = without_bins(without_robot(loop, frame), list(loop.place_targets.values()))
        loop.recorder.frame(loop.camera_name(camera), seen)
        return seen
    raise Abort(
        "camera_failed",
        f"{loop.config.camera_retries} captures failed; last: {errors[-1] if errors else '?'}",
    )


def without_robot(loop: Loop, frame: RGBDFrame) -> RGBDFrame:
    """The frame with no depth reading where it sees the robot itself (`PickConfig.self_filter_margin_m`):
    the arm stands still while the loop observes, so its joints now are its joints at the capture."""
    margin = loop.config.self_filter_margin_m
    if margin is None:
        return frame
    assert frame.T_base_cam is not None  # `capture` refuses frames without one
    seen = robot_free_frame(frame, loop.robot, loop.gripper_geometry, loop.arm.joint_positions(), margin)
    if seen is not frame and logger.isEnabledFor(logging.DEBUG):
        dropped = int(np.count_nonzero(frame.depth_m > 0) - np.count_nonzero(seen.depth_m > 0))
        logger.debug("self-filter: %d depth pixels on the robot dropped", dropped)
    return seen


def estimates(
    loop: Loop,
    run: RunRecord,
    prompt: str,
    min_score_ratio: float | None = None,
    judge: bool = False,
    check: FrameCheck | None = None,
) -> tuple[RGBDFrame, list[ObjectEstimate]]:
    """Capture `observe_frames` frames of the fixed camera and estimate the prompt: the candidates, best first
    (one with a tracker over several frames or an estimator without `estimate_all`). Nothing found is retried
    on fresh frames `camera_retries` times (a transient depth hole or occlusion) before "not_found"; an
    "ambiguous" answer (`judge`) is not retried, and neither is a "not_found" the grounder judged on the
    candidates it saw: asking fresh frames until sensor noise makes one of them clear would turn a refusal
    into a guess (the chance of a spurious clear winner grows with every frame asked)."""
    for k in range(loop.config.camera_retries):
        try:
            return estimates_once(loop, run, prompt, min_score_ratio, judge, check)
        except Abort as exc:
            if exc.reason != "not_found" or exc.judged or k + 1 == loop.config.camera_retries:
                raise
            logger.info("nothing found (%s); observing again", exc.message)
    raise Abort("not_found", "no observation")  # not reached: the loop returns or raises


def estimates_once(
    loop: Loop,
    run: RunRecord,
    prompt: str,
    min_score_ratio: float | None = None,
    judge: bool = False,
    check: FrameCheck | None = None,
    camera: RGBDCamera | None = None,
) -> tuple[RGBDFrame, list[ObjectEstimate]]:
    """Capture (`camera`, the fixed one when None) and estimate; the candidates' estimates, best first (those
    scoring under `min_score_ratio` of the best are not fitted; `candidate_ratio` when None).

    The best estimate's `contenders` (or `AmbiguousObjectError`, whose estimates are then the answer):
    0 is "not_found" (without `judge` only when the candidates together are not likelier than not,
    `_any_fits`); 2 or more is "ambiguous" when `judge` (the command names one object and any of them will
    not do), else the contenders are candidates like any; -1 (not judged) changes nothing."""
    cfg = loop.config
    ratio = cfg.candidate_ratio if min_score_ratio is None else min_score_ratio
    refused: AmbiguousObjectError | None = None
    with run.timed("observe"):
        frames = [capture(loop, run, camera or loop.camera, check) for _ in range(cfg.observe_frames)]
    estimator: Any = loop.estimator  # `estimate_all` is optional (`Estimator`)
    with run.timed("estimate"):
        try:
            if len(frames) > 1:
                ests = [list(estimator.track(frames, prompt))[-1]]
            elif hasattr(estimator, "estimate_all") and cfg.candidates > 1:
                n = cfg.candidates
                ests = list(estimator.estimate_all(frames[0], prompt, max_objects=n, min_score_ratio=ratio))
                if not ests:
                    raise ObjectNotFoundError(f"no object in the frame matches {prompt!r}")
            else:
                ests = [estimator.estimate(frames[0], prompt)]
        except AmbiguousObjectError as exc:  # `estimate` / `track` would not choose among its estimates
            refused, ests = exc, list(exc.estimates)
        except ObjectNotFoundError as exc:
            raise Abort("not_found", str(exc)) from None
        except InvalidInputError as exc:  # e.g. a depth image without a single reading
            raise Abort("not_found", f"the frame cannot be used: {exc}") from None
    frame = frames[-1]
    contenders = int(getattr(ests[0], "contenders", -1)) if ests else -1
    if refused is not None:
        contenders = max(contenders, len(ests), 2)
    if contenders == 0 and (judge or not _any_fits(ests)):
        raise Abort("not_found", f"nothing in the frame fits the words of {prompt!r}", judged=True)
    if judge and contenders >= 2:
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        fit = ests[:contenders]
        message = describe_contenders(prompt, fit, T_base_cam, contenders) if fit else str(refused)
        raise Abort("ambiguous", message, fit, T_base_cam)
    if not ests:  # refused without an estimate to show
        raise Abort("not_found", str(refused))
    return frame, ests


def _any_fits(ests: list[ObjectEstimate]) -> bool:
    """Whether one of the candidates is likelier than not an object the words name, when any of them will
    do: the sum of their match probabilities is at least one half (the probabilities of a frame are those
    of exclusive answers, "this one", "that one", "none", so the sum is the chance that one of them is
    meant). Like things share the mass: five identical cartons at ~0.2 each leave no single one above a
    half, though a carton is surely there. False where the estimates carry no probabilities."""
    p = np.array([float(getattr(e, "probability", np.nan)) for e in ests], dtype=np.float64)
    return bool(len(p) and np.all(np.isfinite(p)) and p.sum() >= 0.5)


def to_base(est: ObjectEstimate, T_base_cam: np.ndarray, name: str) -> tuple[ObjectModel, Plane | None]:
    """An estimate (camera frame) as an `ObjectModel` in base, with its support plane in base (or None)."""
    pose_base = est.pose.transformed(T_base_cam)
    mesh = getattr(est, "mesh_cam", None)
    if mesh is not None:
        mesh = mesh.copy()
        mesh.apply_transform(T_base_cam)
    surface = getattr(est, "surface_cam", None)
    if surface is not None:
        surface = transform_points(T_base_cam, surface)
    target = ObjectModel(
        name, pose_base, mesh=mesh, family=est.prior.name, symmetry=est.prior.symmetry,
        surface_points=surface,
    )  # fmt: skip
    support = None
    if est.support_plane is not None:
        support = Plane.from_camera(est.support_plane.normal_cam, est.support_plane.offset_m, T_base_cam)
    return target, support
