"""Planned grasps adjusted for the estimate's error before they are executed.

A planned grasp sits exactly on the estimated box; the box is off by about a centimetre. These functions
order and nudge grasps so that such an error does not decide the pick, and check that the arm can run a
grasp's straight lines without flipping a wrist:

- `robust_first`: jaw grasps whose pads reach well inside the box first.
- `deepened`: a jaw grasp at the very rim moved deeper along its approach (same IK branch, free approach).
- `pressed`: a suction grasp pressed into its face by the bellows' compliance.
- `lines_continuous`: the approach and lift lines solved every few millimetres without a branch flip.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from typing import Literal, Protocol

import numpy as np

from prompose_grasp.grasp.grippers import GripperGeometry, ParallelJawGeometry, SuctionCupGeometry
from prompose_grasp.grasp.motion import check_path
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import Grasp, ObjectModel
from prompose_grasp.robot.ik import IKResult
from prompose_grasp.robot.model import RobotModel

__all__ = ["LINE_JUMP_RAD", "LINE_STEP_M", "deepened", "lines_continuous", "pressed", "robust_first"]

logger = logging.getLogger(__name__)

#: `lines_continuous` solves IK every this much along a line [m] ...
LINE_STEP_M = 0.005
#: ... and a joint changing more than this between neighbours is a jump, not a motion [rad] (away from
#: singularities a 5 mm tcp step moves no joint more than ~0.03 rad; the validator allows 0.2 per waypoint).
LINE_JUMP_RAD = 0.2
#: The most a grasp is moved deeper along its approach by `deepened` [m].
MAX_DEEPEN_M = 0.03
#: A refined grasp whose IK moves a joint more than this from the planned one is on another branch [rad].
_SAME_BRANCH_RAD = 0.2


class SolvesIK(Protocol):
    """An arm model that solves IK for the tcp (`RobotModel` is one)."""

    def ik(
        self,
        T_base_target: np.ndarray,
        q_seed: np.ndarray | None = ...,
        frame: Literal["flange", "tcp"] = ...,
    ) -> IKResult: ...


def _depth_in_box(grasp: Grasp, target: ObjectModel) -> float:
    """Extent of the target's box behind the tcp along the approach (from the face it enters) [m]."""
    a = grasp.T_base_tcp[:3, 2]
    return float(np.max((target.pose.corners() - grasp.T_base_tcp[:3, 3]) @ -a))


def robust_first(
    grasps: Sequence[Grasp], target: ObjectModel, gripper: GripperGeometry, pad_depth_margin_m: float
) -> list[Grasp]:
    """Parallel-jaw grasps whose pads sit at least half a pad plus `pad_depth_margin_m` inside the estimated
    box (measured from the face the approach enters) first, the rest after, each group in the planner's
    order: a grasp at the very rim of the estimate misses the object when the estimate's top is a centimetre
    high. Other grippers' grasps as they are."""
    if not isinstance(gripper, ParallelJawGeometry):
        return list(grasps)
    pad_half = 0.5 * gripper.pad_depth_m
    flags = [_depth_in_box(g, target) >= pad_half + pad_depth_margin_m for g in grasps]
    return [g for g, f in zip(grasps, flags) if f] + [g for g, f in zip(grasps, flags) if not f]


def deepened(
    grasp: Grasp,
    target: ObjectModel,
    scene: CollisionScene,
    robot: RobotModel,
    gripper: GripperGeometry,
    pad_depth_margin_m: float,
) -> Grasp:
    """A parallel-jaw grasp whose pads reach less than half a pad plus `pad_depth_margin_m` into the
    estimated box (a rim grasp at the very top edge) moved that much deeper along its approach (at most
    `MAX_DEEPEN_M`), when the deeper grasp has IK on the same branch and its approach from the pre-grasp is
    free (jaws open, the target included): pads at the rim's top close above it when the estimate is a
    centimetre high. A section grasp's depth is planned from the seen surface, not from the box: as it is."""
    if not isinstance(gripper, ParallelJawGeometry) or grasp.q is None or grasp.method == "section":
        return grasp
    pad_half = 0.5 * gripper.pad_depth_m
    a = grasp.T_base_tcp[:3, 2]
    extra = min(pad_half + pad_depth_margin_m - _depth_in_box(grasp, target), MAX_DEEPEN_M)
    if extra <= 0.002:
        return grasp
    T = np.array(grasp.T_base_tcp)
    T[:3, 3] += extra * a
    ik = robot.ik(T, q_seed=grasp.q, frame="tcp")
    pre = robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
    if not (ik.success and pre.success) or float(np.max(np.abs(ik.q - grasp.q))) > _SAME_BRANCH_RAD:
        return grasp
    opening = float(grasp.opening_m)  # the open margin is planned into the opening
    _, hit = check_path(robot, scene, np.array([pre.q, ik.q]), gripper, opening, True)
    if hit is not None:
        return grasp
    retreat = np.array(grasp.T_base_retreat)
    retreat[:3, 3] += extra * a
    logger.info("grasp moved %.1f mm deeper along its approach", 1e3 * extra)
    return dataclasses.replace(grasp, T_base_tcp=T, q=ik.q, T_base_retreat=retreat)


def pressed(grasp: Grasp, robot: SolvesIK, gripper: GripperGeometry) -> Grasp:
    """A suction grasp pressed `compliance_m` into its face along the approach (the bellows give; the cup
    seals although the estimated face is a few millimetres off), when IK stays on its branch; other grasps
    as they are."""
    press = gripper.compliance_m if isinstance(gripper, SuctionCupGeometry) else 0.0
    if grasp.method != "suction" or press <= 0 or grasp.q is None:
        return grasp
    T = np.array(grasp.T_base_tcp)
    T[:3, 3] += press * T[:3, 2]
    ik = robot.ik(T, q_seed=grasp.q, frame="tcp")
    if not ik.success or float(np.max(np.abs(ik.q - grasp.q))) > _SAME_BRANCH_RAD:
        return grasp
    return dataclasses.replace(grasp, T_base_tcp=T, q=ik.q)


def lines_continuous(robot: SolvesIK, grasp: Grasp) -> bool:
    """The approach (pre-grasp -> grasp) and the lift (grasp -> retreat) as the arm's `move_linear` runs them:
    IK every `LINE_STEP_M` along the line, each seeded with the last; False when a joint jumps more than
    `LINE_JUMP_RAD` between neighbours (a branch flip near a wrist singularity: the arm's validator refuses
    such a line halfway) or a point has no IK."""
    if grasp.q is None:
        return True
    pre = robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
    if not pre.success:
        return False
    for T0, T1, q0 in (
        (grasp.T_base_pregrasp, grasp.T_base_tcp, pre.q),
        (grasp.T_base_tcp, grasp.T_base_retreat, np.asarray(grasp.q, dtype=np.float64)),
    ):
        dp = np.asarray(T1[:3, 3]) - np.asarray(T0[:3, 3])
        n = max(2, math.ceil(float(np.linalg.norm(dp)) / LINE_STEP_M))
        q_prev = np.asarray(q0, dtype=np.float64)
        for frac in np.linspace(1.0 / n, 1.0, n):
            T = np.array(T1, dtype=np.float64)
            T[:3, 3] = np.asarray(T0[:3, 3]) + frac * dp
            ik = robot.ik(T, q_seed=q_prev, frame="tcp")
            if not ik.success or float(np.max(np.abs(ik.q - q_prev))) > LINE_JUMP_RAD:
                return False
            q_prev = ik.q
    return True
