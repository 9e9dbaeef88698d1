"""Commands to the gripper and the arm's simple moves, each noting what the gripper was told (`Grip`: the
stop path after a device fault opens only what cannot drop anything)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from prompose_grasp.errors import UnreachableError, UnsafeCommandError
from prompose_grasp.grasp.grippers import ParallelJawGeometry
from prompose_grasp.grasp.types import Grasp
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.record import Abort, Grip, RunRecord

__all__ = [
    "close_jaws",
    "go_home",
    "moving_closed",
    "open_for",
    "open_jaws",
    "release_and_back_off",
    "safe",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")


def close_jaws(loop: Loop, run: RunRecord) -> None:
    """Close the gripper with its holding force (the jaw force per finger, `grip_force_n`; a suction cup's
    full force, vacuum on), noting it for the stop path."""
    run.grip = Grip(closed=True)
    loop.gripper.close(loop.gripper_geometry.holding_force_n(loop.config.grip_force_n))


def open_jaws(loop: Loop, run: RunRecord) -> None:
    """Open the gripper fully (vacuum off), noting it for the stop path."""
    loop.gripper.open()
    run.grip = Grip()


def moving_closed(run: RunRecord) -> None:
    """An arm motion starts: with the gripper closed, the object may leave its support from now on."""
    run.grip.lifted = run.grip.closed


def open_for(loop: Loop, run: RunRecord, grasp: Grasp) -> None:
    """Open the jaws to the grasp's planned opening, margin included (fully when the gripper cannot open
    part way, or for suction: release)."""
    geometry = loop.gripper_geometry
    open_to: Any = getattr(loop.gripper, "open_to", None)  # an optional method of jaw grippers
    if isinstance(geometry, ParallelJawGeometry) and callable(open_to) and grasp.opening_m > 0:
        open_to(min(geometry.stroke_m, float(grasp.opening_m)))
        run.grip = Grip()
    else:
        open_jaws(loop, run)


def safe(what: str, command: Callable[[], T]) -> T:
    """Run one arm command; a refusal by the validator or IK is an "ik_failed" attempt."""
    try:
        return command()
    except UnreachableError as exc:
        raise Abort("ik_failed", f"{what}: {exc}") from None
    except UnsafeCommandError as exc:
        raise Abort("ik_failed", f"{what} refused by the validator: {exc}") from None


def release_and_back_off(loop: Loop, run: RunRecord, grasp: Grasp) -> None:
    """Open, then back off along the grasp's lift line (a refused back-off is logged, not raised)."""
    open_jaws(loop, run)
    cfg = loop.config
    try:
        loop.arm.move_linear(grasp.T_base_retreat, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
    except (UnreachableError, UnsafeCommandError) as exc:
        logger.warning("could not back off after a failed grasp: %s", exc)


def go_home(loop: Loop, q_home: np.ndarray) -> None:
    """Back to where the run started, out of the camera's view, before observing again. Joints whose
    range exceeds a turn go to the nearest equivalent angle (q + 2 pi k within the limits: the same
    pose), not back the long way (after a transfer the pan can be more than half a turn away)."""
    cfg = loop.config
    q_now = loop.joints()
    q_goal = np.array(q_home, dtype=np.float64)
    lower, upper = loop.robot.joint_limits
    for j in range(len(q_goal)):
        options = [q_goal[j] + 2.0 * math.pi * k for k in (-1, 0, 1)]
        options = [v for v in options if lower[j] + 1e-3 <= v <= upper[j] - 1e-3] or [q_goal[j]]
        q_goal[j] = min(options, key=lambda v: abs(v - q_now[j]))
    # A joint more than 3 rad away (the validator takes at most half a turn per move) goes in two moves.
    steps = [0.5 * (q_now + q_goal), q_goal] if np.max(np.abs(q_goal - q_now)) > 3.0 else [q_goal]
    try:
        for q in steps:
            loop.arm.move_joints(q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2)
    except (UnreachableError, UnsafeCommandError) as exc:
        logger.warning("could not return to the start configuration: %s", exc)
