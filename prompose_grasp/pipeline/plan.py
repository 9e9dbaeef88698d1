"""Plan: grasps on the chosen candidate, the collision scene they are checked in, and the scene for the
moves while the object is held (place commands)."""

from __future__ import annotations

import dataclasses

import numpy as np

from prompose_grasp.errors import NoFeasibleGrasp
from prompose_grasp.grasp import GraspConfig, ObjectModel, Plane, plan_grasps
from prompose_grasp.grasp.bins import bin_walls
from prompose_grasp.grasp.extent import carried, height, overlaps, plane_z
from prompose_grasp.grasp.motion import place_support_fixture
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.place_targets import no_room
from prompose_grasp.grasp.planner import build_scene
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import GraspPlan
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.outcome import Reason
from prompose_grasp.pipeline.record import Abort, RunRecord

__all__ = ["carried_target", "choose_and_plan", "grasp_config", "held_scene", "plan"]

#: Observed points this close to a place surface are the surface itself [m] (sensor noise at 1-2 m).
_SURFACE_BAND_M = 0.02


def carried_target(loop: Loop, obs: Observation) -> ObjectModel:
    """The target as carried and put down (`grasp.extent.carried`, capped at `max_object_height_m`)."""
    return carried(obs.target, obs.support, loop.config.max_object_height_m)


def _bin_walls(loop: Loop) -> list[ObjectModel]:
    """The walls of the cell's bins as fixture boxes: their readings left the frame at capture (`observe`),
    so the collision scene holds them from the cell's layout."""
    return [w for t in loop.place_targets.values() for w in bin_walls(t)]


def grasp_config(loop: Loop, obs: Observation) -> GraspConfig:
    """The planner's settings for this target: the lift clears the object's own height, and the opening
    includes `open_margin_m` (half on each side), so the approach is checked at the commanded width."""
    cfg = loop.config.grasp or GraspConfig()
    h = height(carried_target(loop, obs), obs.support)
    lift = min(max(cfg.lift_m, h + loop.config.lift_clearance_m), loop.config.max_lift_m)
    clearance = cfg.clearance_m + 0.5 * loop.config.open_margin_m
    return dataclasses.replace(cfg, lift_m=lift, clearance_m=clearance)


def plan(loop: Loop, run: RunRecord, obs: Observation, q_now: np.ndarray) -> tuple[GraspPlan, CollisionScene]:
    """Grasps on the target, ranked, with the scene they were checked in; "ik_failed" when most candidates
    failed on reach, else "no_feasible_grasp"."""
    with run.timed("plan"):
        cfg = grasp_config(loop, obs)
        try:
            grip = loop.gripper_geometry
            P = obs.points_base
            walls = _bin_walls(loop)
            scene = build_scene(obs.target, loop.robot, grip, walls, obs.support, P, obs.q_seen, cfg)
            grasps = plan_grasps(obs.target, loop.robot, grip, q_seed=q_now, config=cfg, scene=scene)
        except NoFeasibleGrasp as exc:
            reach = sum(v for k, v in exc.rejected.items() if k.startswith("ik"))
            reason: Reason = (
                "ik_failed" if reach * 2 >= max(1, sum(exc.rejected.values())) else "no_feasible_grasp"
            )
            raise Abort(reason, str(exc)) from None
    loop.recorder.grasps(grasps)
    return grasps, scene


def choose_and_plan(
    loop: Loop, run: RunRecord, observations: list[Observation], place_target: PlaceTarget | None
) -> tuple[Observation, GraspPlan, CollisionScene]:
    """The first candidate with a feasible grasp (and room at the place target), its plan and scene; the
    first candidate's failure when none has one."""
    q_now = loop.joints()
    loop.emit("plan", "planning grasps", 0.3)
    plan_failure: Abort | None = None
    for candidate in observations:
        if no_room(carried_target(loop, candidate), place_target):
            plan_failure = plan_failure or Abort(
                "no_feasible_grasp", "no feasible place pose (rejected: no_room: the estimate is larger)"
            )
            continue
        try:
            grasps, scene = plan(loop, run, candidate, q_now)
        except Abort as exc:
            plan_failure = plan_failure or exc
            continue
        if candidate is not observations[0]:  # the estimate actually used comes last in the outcome
            run.acted_on(candidate.estimate, candidate.frame.T_base_cam)
        return candidate, grasps, scene
    raise plan_failure or Abort("no_feasible_grasp", "no candidate to plan for")


def held_scene(loop: Loop, run: RunRecord, obs: Observation, target: PlaceTarget) -> CollisionScene:
    """The scene for the moves while the object is held and for place planning: the observed points
    without the object's own (they leave with it), without the place surface's own (the floor of a bin,
    the deck of a pallet: the object is put down on them) and without the arm's; what this run already
    put down as boxes; the lower of the pick support and the place surface as the support plane."""
    with run.timed("plan"):
        P = obs.points_base
        T_surf = target.T_base_surface
        local = (P - T_surf[:3, 3]) @ T_surf[:3, :3]
        on_surface = np.all(np.abs(local[:, :2]) <= target.half_extents_xy_m, axis=1) & (
            np.abs(local[:, 2]) < _SURFACE_BAND_M
        )
        P = P[~on_surface]
        place_plane = Plane(T_surf[:3, 2], -float(T_surf[:3, 2] @ T_surf[:3, 3]))
        support = place_plane
        if obs.support is not None and plane_z(obs.support) < plane_z(place_plane):
            support = obs.support
        obstacles = [o for o in run.placed if not overlaps(o, obs.target)]
        obstacles += _bin_walls(loop)
        body = place_support_fixture(target)  # a conveyor's body below its belt: often not in this view
        if body is not None:
            obstacles.append(body)
        cfg = loop.config.grasp or GraspConfig()
        return build_scene(
            obs.target, loop.robot, loop.gripper_geometry, obstacles, support, P, obs.q_seen, cfg
        )
