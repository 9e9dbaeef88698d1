"""Verify: is the object held, and is it the object named?

The jaws must have stopped on something (the gripper's own detection) no narrower than `min_jaw_width_m`,
or half the planned contact width for a thinner part (a cup's 2 mm wall); after a pick the camera must no
longer see the object where it stood, nor see it hang from the jaws with a part still on the support (it
rose less than half the lift and some of its seen points lie on the support: a pan held by the far side of
its rim, its handle on the table). What is held must be the object named (`wrong_object`).

Verification fails closed. A re-observation frame must have depth readings on at least half the pixels the
pick's view had them on (`depth_gone`: a sensor dropout): a frame that fails is captured again,
`camera_retries` times in all; then a lifted object is set down where it was picked (`set_down`) and the run
ends "camera_failed". A re-observation that finds no object is judged on the raw depth where the object stood
(`vacated`): still reading its surface is "slipped", no longer reading it (seen past it, or the hand in
front) is a lift; too few readings there is a lift only while the gripper holds something (the held object
nearer than the sensor reads), else no evidence ("camera_failed", set down).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

from prompose_grasp.errors import UnreachableError, UnsafeCommandError
from prompose_grasp.geometry.pointcloud import back_project, valid_depth_mask
from prompose_grasp.geometry.se3 import invert_T, transform_points
from prompose_grasp.grasp import ObjectModel, Plane
from prompose_grasp.grasp.extent import top_height
from prompose_grasp.grasp.grippers import ParallelJawGeometry
from prompose_grasp.grasp.types import Grasp
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.hand import open_jaws, release_and_back_off
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation, estimates
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.seams import ObjectEstimate
from prompose_grasp.pipeline.wrong_object import (
    HELD_XY_SLACK_M,
    STOOD_MARGIN_M,
    STOOD_MIN_POINTS,
    across,
    put_back,
    wrong_object,
)
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["depth_gone", "reobserve", "set_down", "vacated", "verify_held"]

#: Jaws closed narrower than this held nothing, whatever the planned width (the 2F-85 class reads 0 when
#: closed on nothing; the sim's gripper reads negative) [m].
_MIN_JAW_FLOOR_M = 0.001
#: Seen points this close to the support rest on it (depth noise and the plane fit put an object's points
#: on the support within about a centimetre of the plane); a held object's part rests on the support when
#: this share of its mask's points, and at least this many, lie there.
_RESTING_M = 0.015
_RESTING_SHARE = 0.01
_RESTING_MIN_POINTS = 3
#: A re-observation is trusted only with depth readings on at least this share of the pixels that had one in
#: the pick's view: a lift changes the readings where the object stood and where the hand passes, a small part
#: of the image; a sensor fault or a saturated projector takes them from the whole frame.
_DEPTH_KEPT_SHARE = 0.5
#: A depth reading within this of where the pick's view saw the object's surface is that surface (sensor
#: noise at ~1 m is a few millimetres to 1 cm; a lifted object is at least 10 cm from where it stood) [m].
_SAME_SURFACE_M = 0.02
#: The object is still where it stood when at least this share of the readings there are its surface [-].
_STILL_SHARE = 0.5


def verify_held(loop: Loop, run: RunRecord, grasp: Grasp) -> float:
    """The jaw width after closing [m]; "slipped" (released, backed off) when the gripper holds nothing: no
    detection, or jaws closed narrower than `min_jaw_width_m` (half the planned contact width for a thinner
    part, at least `_MIN_JAW_FLOOR_M`)."""
    with run.timed("verify"):
        loop.emit("verify", "checking the grip", 0.7)
        width = float(loop.gripper.width())
        held = bool(loop.gripper.grasp_detected())
        jaws = isinstance(loop.gripper_geometry, ParallelJawGeometry)
        if jaws:
            # A thin wall (a paper cup's 2 mm rim) stops the jaws below `min_jaw_width_m`: the floor is
            # then half the planned contact width.
            floor = min(loop.config.min_jaw_width_m, 0.5 * float(getattr(grasp, "width_m", 0.0) or 0.0))
            held = held and width >= max(floor, _MIN_JAW_FLOOR_M)
        if not held:
            release_and_back_off(loop, run, grasp)
            what = f"jaw width {1e3 * width:.1f} mm" if jaws else "no seal"
            raise Abort("slipped", f"nothing held after closing ({what})")
    return width


def reobserve(
    loop: Loop, run: RunRecord, cmd: Command, obs: Observation, grasp: Grasp, slip_check: bool = True
) -> None:
    """After the lift: the object must no longer be seen where it stood (`slip_check`), and what is held
    must be the object named (`wrong_object`; else it is put back and the attempt is "wrong_object").

    A candidate moved when its centre moved or its top rose by `moved_min_m`, or its lowest seen points
    are that high above the support: the lifted object seen in the hand is partly hidden by the gripper
    and its amodal box can reach down to the table (a 31 cm bottle lifted 34 cm was estimated 0.36 m
    tall, centre 31 mm from where it stood, top 56 mm higher)."""
    if not loop.config.reobserve:
        return
    loop.emit("verify", "re-observing", 0.8)
    before, support = obs.target, obs.support
    try:
        # Every candidate: one that fits the prompt better may have scored under the ratio before. A
        # frame without depth where the object stood shows nothing about it (`depth_gone`).
        frame, ests = estimates(
            loop, run, cmd.object_prompt, 0.0, check=functools.partial(depth_gone, obs=obs)
        )
    except Abort as exc:
        if exc.reason == "camera_failed":  # no frame to judge the lift on: set it down, unverified
            set_down(loop, run, grasp, f"the lift could not be verified: {exc.message}")
        if exc.reason != "not_found":
            raise
        # Nothing seen is no evidence by itself; the depth where the object stood is (the robot's own
        # readings kept: a hand in front of that place is something there): read as it was, the object
        # is still there; no longer (seen past it, or something in front: the hand, the object in it),
        # it is not where it stood.
        gone = vacated(run.last_raw_frame, obs)
        if gone is None and loop.gripper.grasp_detected():
            # no readings where it stood, and the gripper holds something: the object in the hand is in
            # front of that place, nearer than the sensor reads (a camera's minimum range); an object that
            # fell back or never rose would leave the jaws or the cup empty
            return
        if gone is None:
            set_down(
                loop, run, grasp, "the lift could not be verified: the re-observation sees no object and too "
                "few depth readings where it stood",
            )  # fmt: skip
        if not gone and slip_check:
            open_jaws(loop, run)
            raise Abort(
                "slipped", "no object seen, but the depth where it stood still reads its surface"
            ) from None
        return
    with run.timed("verify"):
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        top_before = top_height(before, support)
        heights = [seen_heights(e, frame, support) for e in ests]  # each estimate's, once
        lowest = [-math.inf if h is None else float(np.percentile(h, 5.0)) for h in heights]

        def displacement(k: int) -> float:
            after = ObjectModel("target", ests[k].pose.transformed(T_base_cam))
            rise = top_height(after, support) - top_before
            # it stood on the support: its lowest seen points that high above it rose at least that much
            return max(float(np.linalg.norm(after.pose.t - before.pose.t)), rise, lowest[k])

        # Any candidate still standing where the target stood means it was not lifted (those within
        # `candidate_ratio` of the best score, as fitted before every candidate was).
        best = max(float(getattr(e, "score", 1.0)) for e in ests)
        floor = loop.config.candidate_ratio * best
        near = [k for k, e in enumerate(ests) if float(getattr(e, "score", 1.0)) >= floor]
        moves = [displacement(k) for k in near]
        est, moved = ests[near[int(np.argmin(moves))]], min(moves)
        wrong = wrong_object(loop, cmd, obs, frame, ests, lowest)
    run.acted_on(est, T_base_cam)
    if slip_check and moved < loop.config.moved_min_m:
        open_jaws(loop, run)
        raise Abort("slipped", f"the object is still where it stood (moved {1e3 * moved:.0f} mm)")
    resting = _resting_part(loop, obs, grasp, ests, heights, T_base_cam) if slip_check else None
    if resting is not None:
        open_jaws(loop, run)
        raise Abort("slipped", resting)
    if wrong is not None:
        put_back(loop, run, cmd, obs, grasp, frame, *wrong)


def _resting_part(
    loop: Loop,
    obs: Observation,
    grasp: Grasp,
    ests: Sequence[ObjectEstimate],
    heights: Sequence[np.ndarray | None],
    T_base_cam: np.ndarray,
) -> str | None:
    """Why the lifted object is not off the support, or None: the candidate that moved most among those
    under the tcp (centre within half the object's largest extent plus `HELD_XY_SLACK_M`, across) that
    rose by half `moved_min_m` or more rose less than half the lift, and some of its seen points
    (`_RESTING_SHARE` of them, at least `_RESTING_MIN_POINTS`: a tip is a small part of a mask) lie within
    `_RESTING_M` of the support. It hangs from the jaws with a part still resting on the support: a pan
    held by the far side of its rim, its handle on the table, tilts and drags instead of rising. (A bowl
    held by its rim hangs tilted too and its centre rises about half the lift, but all of it is in the
    air.)"""
    support = obs.support
    if support is None or not ests:
        return None
    up = np.asarray(support.normal, dtype=np.float64)
    lift = float((np.asarray(grasp.T_base_retreat)[:3, 3] - np.asarray(grasp.T_base_tcp)[:3, 3]) @ up)
    tcp = np.asarray(loop.robot.fk_tcp(loop.arm.joint_positions()), dtype=np.float64)[:3, 3]
    reach = 0.5 * float(np.max(obs.target.pose.size)) + HELD_XY_SLACK_M
    before = obs.target.pose.t
    under = [
        (float(np.linalg.norm(p.t - before)), k, float((p.t - before) @ up))
        for k, p in enumerate(e.pose.transformed(T_base_cam) for e in ests)
        if across(p.t, tcp) <= reach
    ]
    # the held one rose: an object standing under the hand (a neighbour of a tall bottle) re-estimates
    # within about a centimetre or two of where it stood, up or down
    under = [u for u in under if u[2] >= 0.5 * loop.config.moved_min_m]
    if not under or lift <= 0.0:
        return None
    _, k, rise = max(under)
    h = heights[k]
    if h is None:
        return None
    on_support = int(np.count_nonzero(h < _RESTING_M))
    if rise < 0.5 * lift and on_support >= max(_RESTING_MIN_POINTS, _RESTING_SHARE * len(h)):
        return (
            f"the object hangs from the jaws with a part still on the support (its centre rose "
            f"{1e3 * rise:.0f} mm of the {1e3 * lift:.0f} mm lift)"
        )
    return None


def set_down(loop: Loop, run: RunRecord, grasp: Grasp, why: str) -> None:
    """Set a lifted object down where it was picked when the lift cannot be verified (the lift line back
    down to the grasp pose, validated before it is sent, then open and back off), and end the attempt
    "camera_failed" with `why`; when the way down is refused the object stays held, and the message says
    so."""
    cfg = loop.config
    try:
        for T in (grasp.T_base_tcp, grasp.T_base_retreat):
            loop.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        loop.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
    except (UnreachableError, UnsafeCommandError) as exc:
        raise Abort(
            "camera_failed", f"{why}; it could not be set down ({exc}): the gripper still holds it"
        ) from None
    release_and_back_off(loop, run, grasp)
    raise Abort("camera_failed", f"{why}; the object was set down where it was picked")


def seen_heights(est: ObjectEstimate, frame: RGBDFrame, support: Plane | None) -> np.ndarray | None:
    """Heights above the support [m] of the depth points of `est`'s mask (in the frame's base frame); None
    without a mask, a support or 10 points. Something standing on the support shows points near it;
    something held in the air does not."""
    mask = getattr(est, "mask", None)
    if support is None or mask is None or frame.T_base_cam is None:
        return None
    pts = back_project(frame.depth_m, frame.intrinsics, mask)
    if len(pts) < 10:
        return None
    return support.height(transform_points(np.asarray(frame.T_base_cam, dtype=np.float64), pts))


def depth_gone(frame: RGBDFrame, obs: Observation) -> str | None:
    """Why a re-observation frame cannot be trusted, or None: it has depth readings on fewer than
    `_DEPTH_KEPT_SHARE` of the pixels the pick's view had them on, over the whole image. A sensor fault or a
    saturated projector takes the frame's readings; a lifted object takes only those where it stood (a
    carton lifted towards a camera above a conveyor comes inside the sensor's minimum range), which
    `vacated` judges."""
    had = int(np.count_nonzero(valid_depth_mask(obs.frame.depth_m)))
    if had == 0:
        return None
    has = int(np.count_nonzero(valid_depth_mask(frame.depth_m)))
    if has >= _DEPTH_KEPT_SHARE * had:
        return None
    return f"the depth is gone from the frame ({has} readings, the pick's view had {had})"


def vacated(frame: RGBDFrame | None, obs: Observation) -> bool | None:
    """Does the depth of `frame` show that the object of `obs` left where it stood? The pick's observed points
    of the object (inside its box, above the support, as `wrong_object.stood_before`) are looked up in
    `frame`: True when fewer than `_STILL_SHARE` of the readings there lie on its surface (within
    `_SAME_SURFACE_M`: seen past it, or something in front of it); False when more do (it is still there);
    None when there are fewer than `STOOD_MIN_POINTS` readings to tell."""
    if frame is None or frame.T_base_cam is None:
        return None
    P = obs.points_base
    pose = obs.target.pose
    local = (P - pose.t) @ pose.R
    grow = STOOD_MARGIN_M if obs.support is not None else 0.0
    inside = np.all(np.abs(local) <= 0.5 * np.asarray(pose.size) + grow, axis=1)
    if obs.support is not None:
        inside &= P @ np.asarray(obs.support.normal) + obs.support.offset_m > STOOD_MARGIN_M
    X = transform_points(invert_T(np.asarray(frame.T_base_cam, dtype=np.float64)), P[inside])
    X = X[X[:, 2] > 0]
    K = frame.intrinsics
    u = np.rint(K.fx * X[:, 0] / X[:, 2] + K.cx).astype(np.int64)
    v = np.rint(K.fy * X[:, 1] / X[:, 2] + K.cy).astype(np.int64)
    in_image = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    depth = frame.depth_m[v[in_image], u[in_image]]
    read = valid_depth_mask(depth)
    if int(np.count_nonzero(read)) < STOOD_MIN_POINTS:
        return None
    still = np.abs(depth[read] - X[in_image][read, 2]) <= _SAME_SURFACE_M
    return bool(np.mean(still) < _STILL_SHARE)
