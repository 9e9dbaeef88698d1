"""The wrist look: with a camera on the arm, look at the target from above the best grasp before grasping;
the closer estimate replaces the fixed camera's (tracking the target on approach)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from prompose_grasp.errors import CameraError, UnreachableError, UnsafeCommandError
from prompose_grasp.geometry.se3 import invert_T
from prompose_grasp.grasp import check_path
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import Grasp, ObjectModel
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation, estimates_once, to_base
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["aim_camera", "with_first_view", "wrist_look", "wrist_mount"]

logger = logging.getLogger(__name__)


def wrist_look(
    loop: Loop, run: RunRecord, obs: Observation, grasp: Grasp, scene: CollisionScene, cmd: Command
) -> Observation | None:
    """Move the wrist camera above the target (the best grasp's pre-grasp, `wrist_look_m` higher), observe
    and estimate there; when the target is not seen from there, look once more from that pose moved
    sideways so that the camera's optical axis runs through the target (the camera sits beside the tool:
    along the tool's axis a target at the reach's far end lies at the image's edge, half behind the
    fingers). The observation with the wrist's estimate, or None (no look pose, nothing seen, or an
    estimate too far from the first: another object)."""
    T_look = np.array(grasp.T_base_pregrasp)
    T_look[:3, 3] -= loop.config.wrist_look_m * T_look[:3, 2]  # further back along the approach
    seen = _look_from(loop, run, T_look, grasp.q, obs, scene, cmd)
    if seen is not None:
        return seen
    T_flange_cam = wrist_mount(loop)
    if T_flange_cam is None:
        return None
    T_tcp_cam = invert_T(loop.robot.T_flange_tcp) @ T_flange_cam
    centred = aim_camera(T_look, T_tcp_cam, obs.target.pose.t)
    # Seeded with the joints now (at the first look, a few centimetres away): the nearest branch, not a
    # turn of the wrist that costs seconds of motion.
    return _look_from(loop, run, centred, None, obs, scene, cmd)


def _look_from(
    loop: Loop,
    run: RunRecord,
    T_look: np.ndarray,
    q_seed: np.ndarray | None,
    obs: Observation,
    scene: CollisionScene,
    cmd: Command,
) -> Observation | None:
    """Move the tcp to `T_look` (when reachable, the move free and valid), observe with the wrist camera
    and estimate; the observation whose estimate is nearest the first (within `wrist_max_shift_m`). IK
    is seeded with `q_seed`, or the joints now when None."""
    cfg = loop.config
    q_now = loop.joints()
    ik = loop.robot.ik(T_look, q_seed=q_now if q_seed is None else q_seed, frame="tcp")
    if not ik.success:
        return None
    _, hit = check_path(loop.robot, scene, np.array([q_now, ik.q]), loop.gripper_geometry, 0.0, True)
    if hit is not None:
        return None
    try:
        loop.validator.validate_joint_move(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2, q_now)
    except UnsafeCommandError:
        return None
    loop.emit("observe", "looking with the wrist camera", 0.35)
    with run.timed("execute"):
        try:
            loop.arm.move_joints(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.info("wrist look refused: %s", exc)
            return None
    try:
        frame, ests = estimates_once(loop, run, cmd.object_prompt, camera=loop.wrist_camera)
    except Abort as exc:
        logger.info("wrist camera: %s", exc.message)
        return None
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    best = None
    for est in ests:
        target, _ = to_base(est, T_base_cam, "target")
        shift = float(np.linalg.norm(target.pose.t - obs.target.pose.t))
        if shift <= cfg.wrist_max_shift_m and (best is None or shift < best[0]):
            best = (shift, est, target)
    if best is None:
        logger.info("wrist camera: no %r within %.0f mm of the first view", cmd.object_prompt,
                    1e3 * cfg.wrist_max_shift_m)  # fmt: skip
        return None
    shift, est, target = best
    run.acted_on(est, T_base_cam)
    loop.emit("estimate", f"wrist camera: the target is {1e3 * shift:.0f} mm from the first view", 0.4)
    return Observation(obs.frame, est, with_first_view(target, obs.target), obs.support, obs.points_base,
                       obs.q_seen)  # fmt: skip


def with_first_view(target: ObjectModel, first: ObjectModel) -> ObjectModel:
    """The wrist's target, its seen surface joined by the first view's: the object has not moved between the
    two looks, and each camera sees parts of it the other does not (from above, the wrist sees tops; the
    fixed camera sees sides, an ear or a spout that a fit from above leaves out). The grasp planner keeps the
    jaws off all of it (`grasp.planner`, "collision_seen")."""
    wrist, fixed = (
        v.surface_points if v.surface_points is not None and len(v.surface_points) else None
        for v in (target, first)
    )
    if fixed is None:
        return target
    joined = fixed if wrist is None else np.concatenate([wrist, fixed])
    return dataclasses.replace(target, surface_points=joined)


def wrist_mount(loop: Loop) -> np.ndarray | None:
    """(4, 4) T_flange_cam of the wrist camera, learned once (kept on `loop`) from a capture at the arm's
    joints now (the arm stands still while the loop observes; the frame's T_base_cam is the camera's
    hand-eye pose chained with the flange's), or None when that capture fails."""
    if loop.T_flange_wrist_cam is None and loop.wrist_camera is not None:
        try:
            frame = loop.wrist_camera.capture()
        except CameraError as exc:
            logger.info("wrist camera mount not learned: %s", exc)
            return None
        if not isinstance(frame, RGBDFrame) or frame.T_base_cam is None:
            return None
        T_flange_base = invert_T(loop.robot.fk(loop.arm.joint_positions()))
        loop.T_flange_wrist_cam = T_flange_base @ np.asarray(frame.T_base_cam, dtype=np.float64)
    return loop.T_flange_wrist_cam


def aim_camera(T_base_tcp: np.ndarray, T_tcp_cam: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(4, 4) the tcp pose `T_base_tcp` moved sideways, its orientation kept, so that the optical axis (+z) of
    the camera it carries at `T_tcp_cam` passes through `point` (3,) in base [m]."""
    T_cam = np.asarray(T_base_tcp, dtype=np.float64) @ np.asarray(T_tcp_cam, dtype=np.float64)
    z = T_cam[:3, 2]
    d = np.asarray(point, dtype=np.float64) - T_cam[:3, 3]
    out = np.array(T_base_tcp, dtype=np.float64)
    out[:3, 3] += d - (d @ z) * z  # the part of the offset across the axis
    return out
