"""Execute: one grasp, and for place commands its transfer and place. Every move passes the validator
before the first is sent, so a plan the arm would refuse halfway is dropped before anything moves."""

from __future__ import annotations

import functools

import numpy as np

from prompose_grasp.errors import NoFeasibleMotion, NoFeasiblePlace, UnsafeCommandError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.grasp import (
    ObjectModel,
    PlaceConfig,
    PlaceTarget,
    check_path,
    plan_pick_place,
    plan_place,
)
from prompose_grasp.grasp.grippers import ParallelJawGeometry
from prompose_grasp.grasp.motion import GripperAction, MotionConfig, free_move, timed_trajectory
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import Grasp
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.hand import close_jaws, moving_closed, open_for, open_jaws, safe
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.outcome import Reason
from prompose_grasp.pipeline.plan import carried_target
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.verify import reobserve, verify_held

__all__ = ["approach", "guards_approach", "pick", "pick_place", "touch_zone_m"]

#: Place candidates examined (the planner's default 200 are all within ~0.3 m of the preferred point: a belt
#: with one carton already at its centre had no free spot among them).
_PLACE_CONFIG = PlaceConfig(max_candidates=2000)


def pick(loop: Loop, run: RunRecord, grasp: Grasp, scene: CollisionScene) -> float:
    """To the pre-grasp (a free joint move, or the grasp layer's detour when the direct line collides),
    approach, close, lift; returns the jaw width after `verify_held` [m]."""
    cfg = loop.config
    with run.timed("execute"):
        q_now = loop.joints()
        ik = loop.robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
        if not ik.success:
            raise Abort("ik_failed", f"pre-grasp: {ik.message}")
        grip = loop.gripper_geometry
        W = np.array([q_now, ik.q])
        _, hit = check_path(loop.robot, scene, W, grip, grasp.opening_m, True)
        if hit is not None:
            # The direct joint line collides: the grasp layer's detour (up, across, down), as for a place.
            try:
                W = free_move(loop.robot, scene, q_now, ik.q, gripper=grip, opening_m=grasp.opening_m)
            except NoFeasibleMotion:
                raise Abort("collision", f"path to the pre-grasp hits {hit.name}: {hit.reason}") from None
        detour = timed_trajectory(loop.robot, W, MotionConfig()) if len(W) > 2 else None
        try:  # every move passes the validator before the first is sent
            if detour is not None:
                loop.validator.validate_trajectory(detour, q_now)
            else:
                loop.validator.validate_joint_move(
                    ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2, q_current=q_now
                )
            for T in (grasp.T_base_tcp, grasp.T_base_retreat):
                loop.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except UnsafeCommandError as exc:
            raise Abort("ik_failed", f"the pick would be refused by the validator: {exc}") from None
        open_for(loop, run, grasp)
        if detour is not None:
            safe("to pre-grasp (detour)", functools.partial(loop.arm.follow, detour))
        else:
            safe(
                "to pre-grasp",
                lambda: loop.arm.move_joints(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2),
            )
        approach(loop, grasp, scene.target)
        close_jaws(loop, run)
        moving_closed(run)
        safe(
            "lift",
            lambda: loop.arm.move_linear(grasp.T_base_retreat, cfg.linear_speed_m_s, cfg.linear_accel_m_s2),
        )
    return verify_held(loop, run, grasp)


def approach(loop: Loop, grasp: Grasp, target: ObjectModel | None) -> None:
    """The straight line from the pre-grasp to the grasp; guarded for open jaws on an arm that measures the
    force at its tool (`PickConfig.approach_contact_force_n`), at the touch speed where the fingers may meet
    the `target` (`touch_zone_m`): on a touch short of the grasp pose (by more than
    `approach_touch_tolerance_m`) the arm backs off to the pre-grasp and the attempt ends "collision"."""
    cfg = loop.config
    T, speed, accel = grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2
    if not guards_approach(loop):
        safe("approach", lambda: loop.arm.move_linear(T, speed, accel))
        return
    limit, grip = cfg.approach_contact_force_n, loop.gripper_geometry
    assert limit is not None and isinstance(grip, ParallelJawGeometry)  # `guards_approach` checked both
    T = np.asarray(T, dtype=np.float64)
    line = T[:3, 3] - np.asarray(grasp.T_base_pregrasp)[:3, 3]
    length = float(np.linalg.norm(line))
    zone = min(length, touch_zone_m(T, target, grip.fingertip_below_tcp_m, cfg.approach_touch_zone_m))
    T_slow = T.copy()
    T_slow[:3, 3] -= zone * line / max(length, 1e-9)
    legs = [(T, cfg.approach_touch_speed_m_s)]
    if length - zone > 1e-3:  # at the approach speed down to the touch zone first
        legs.insert(0, (T_slow, speed))
    if all(_guarded_leg(loop, T_leg, v, accel, limit) for T_leg, v in legs):  # stops at the first touch
        return
    short = float(np.linalg.norm(loop.arm.tcp_pose()[:3, 3] - T[:3, 3]))
    if short <= cfg.approach_touch_tolerance_m:
        return  # the grasp's own contact arriving: close there
    safe("back off after a touch", lambda: loop.arm.move_linear(grasp.T_base_pregrasp, speed, accel))
    raise Abort(
        "collision",
        f"the open jaws touched something {1e3 * short:.0f} mm before the grasp pose (over {limit:g} N on "
        "the approach): a part of the object or a neighbour the plan did not know of; backed off to the "
        "pre-grasp",
    )


def guards_approach(loop: Loop) -> bool:
    """The approach is guarded: a limit is set, the arm measures the force at its tool, the jaws are open
    on the way down (a suction cup's approach ends pressed on its object by design)."""
    return (
        loop.config.approach_contact_force_n is not None
        and loop.arm.senses_contact
        and isinstance(loop.gripper_geometry, ParallelJawGeometry)
    )


def _guarded_leg(loop: Loop, T: np.ndarray, speed: float, accel: float, limit: float) -> bool:
    """One guarded line of the approach; False when it stopped on contact."""
    return safe("approach", lambda: loop.arm.move_linear_until_contact(T, speed, accel, limit))


def touch_zone_m(T_grasp: np.ndarray, target: ObjectModel | None, tip_m: float, margin_m: float) -> float:
    """How far before the grasp pose (along its approach, the tcp's +z) the open fingertips come within
    `margin_m` of the target's box: where its nearest face lies across their way, plus the margin [m]
    (just the margin without a target)."""
    if target is None:
        return margin_m
    a = T_grasp[:3, 2]
    tips = T_grasp[:3, 3] + tip_m * a
    ahead = (target.pose.corners() - tips) @ a  # > 0: beyond where the tips stop
    return max(0.0, -float(np.min(ahead))) + margin_m


def pick_place(
    loop: Loop,
    run: RunRecord,
    obs: Observation,
    grasp: Grasp,
    target: PlaceTarget,
    scene: CollisionScene,
    held_scene: CollisionScene,
    attempt: int,
    cmd: Command,
) -> float:
    """Plan the place and the whole motion (pick, transfer, place), validate every segment, then run it:
    after the lift the grip is verified and the held object checked (`reobserve` without the slip check: a
    slip shows at the descent); returns the jaw width [m]."""
    q_now = loop.joints()
    carried = carried_target(loop, obs)
    with run.timed("plan"):
        try:
            place = plan_place(
                carried,
                grasp,
                target,
                loop.robot,
                loop.gripper_geometry,
                obstacles=tuple(run.placed),
                q_seed=grasp.q,
                config=_PLACE_CONFIG,
                scene=held_scene,
            )
            motion = plan_pick_place(
                loop.robot, grasp, place, carried, scene, held_scene, loop.gripper_geometry, q_now
            )
        except NoFeasiblePlace as exc:  # the cause, when there is one: e.g. the pallet pattern's misfit
            cause = f" ({exc.__cause__})" if exc.__cause__ is not None else ""
            raise Abort("no_feasible_grasp", f"{exc}{cause}") from None
        except NoFeasibleMotion as exc:
            reason: Reason = "ik_failed" if "IK" in exc.reason else "collision"
            raise Abort(reason, str(exc)) from None
    q = q_now
    for seg in motion.segments:  # the whole motion passes the validator before anything moves
        try:
            loop.validator.validate_trajectory(seg.trajectory, q)
        except UnsafeCommandError as exc:
            raise Abort("ik_failed", f"{seg.name} would be refused by the validator: {exc}") from None
        q = np.asarray(seg.trajectory.q[-1], dtype=np.float64)
    run.place = place
    width = 0.0
    with run.timed("execute"):
        open_for(loop, run, grasp)
    for seg in motion.segments:
        with run.timed("execute"):
            loop.emit("place" if seg.holding else "execute", f"segment {seg.name}", 0.5, attempt)
            moving_closed(run)
            if seg.gripper_after is GripperAction.CLOSE and guards_approach(loop):
                # the approach's straight line, guarded as a pick's is (its end is the grasp pose)
                approach(loop, grasp, obs.target)
            else:
                safe(seg.name, functools.partial(loop.arm.follow, seg.trajectory))
            if seg.gripper_after is GripperAction.CLOSE:
                close_jaws(loop, run)
            elif seg.gripper_after is GripperAction.OPEN:
                if seg.holding and not loop.gripper.grasp_detected():  # let go of what is no longer held
                    open_jaws(loop, run)
                    raise Abort("slipped", "the object was lost during the transfer")
                open_for(loop, run, grasp)
        if seg.name == "lift":
            width = verify_held(loop, run, grasp)
            # Held is the object named? (a slip shows at the descent: no slip check here)
            reobserve(loop, run, cmd, obs, grasp, slip_check=False)
    placed = ObjectModel(
        f"placed {len(run.placed) + 1}",
        Pose9D(place.T_base_obj[:3, :3], place.T_base_obj[:3, 3], carried.pose.size),
    )
    run.placed.append(placed)
    return width
