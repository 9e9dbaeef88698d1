"""The grasps of one plan, tried best first: each refined for the estimate's error (`grasp.refine`),
executed (`execute`) and verified (`verify`), until one holds, a failure ends the round, or
`grasps_per_estimate` were tried."""

from __future__ import annotations

import logging

from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.refine import deepened, lines_continuous, pressed, robust_first
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import GraspPlan
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.execute import pick, pick_place
from prompose_grasp.pipeline.faults import DEVICE_FAULTS, fault_reason
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.outcome import AttemptRecord
from prompose_grasp.pipeline.plan import held_scene
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.verify import reobserve

__all__ = ["try_grasps"]

logger = logging.getLogger(__name__)


def try_grasps(
    loop: Loop,
    run: RunRecord,
    cmd: Command,
    obs: Observation,
    plan: GraspPlan,
    scene: CollisionScene,
    place_target: PlaceTarget | None,
) -> None:
    """Returns when a grasp held (and placed); raises the last attempt's `Abort` otherwise. A timeout, a
    failed camera and a wrong object end the round at once; a slip ends it too (the object may have moved:
    the next round observes again)."""
    cfg = loop.config
    grasps = robust_first(plan.grasps, obs.target, loop.gripper_geometry, cfg.pad_depth_margin_m)
    scene_held = held_scene(loop, run, obs, place_target) if place_target is not None else None
    failures: list[Abort] = []
    tried = 0
    for i, planned in enumerate(grasps):
        if tried >= cfg.grasps_per_estimate:
            break
        run.check_time(cfg.timeout_s)
        grasp = pressed(planned, loop.robot, loop.gripper_geometry)
        grasp = deepened(grasp, obs.target, scene, loop.robot, loop.gripper_geometry, cfg.pad_depth_margin_m)
        if not lines_continuous(loop.robot, grasp):
            # The arm's linear approach or lift would flip a wrist on the way (refused halfway): skip
            # the grasp before anything moves (it does not count as a try).
            logger.info("grasp %d skipped: its approach or lift line is not continuous in joint space", i)
            continue
        tried += 1
        loop.recorder.grasp_tried(grasp, i)
        n = len(run.attempts) + 1
        loop.emit(
            "execute", f"grasp {i + 1}/{len(plan)} ({grasp.method}, quality {grasp.quality:.2f})", 0.45, n
        )
        try:
            if place_target is None or scene_held is None:
                width = pick(loop, run, grasp, scene)
                reobserve(loop, run, cmd, obs, grasp)
            else:
                width = pick_place(loop, run, obs, grasp, place_target, scene, scene_held, n, cmd)
        except DEVICE_FAULTS as exc:  # the run ends (`PickAndPlace.run`): the attempt says where it struck
            _attempted(loop, run, AttemptRecord(n, grasp, fault_reason(exc), str(exc)))
            raise
        except Abort as exc:
            _attempted(loop, run, AttemptRecord(n, grasp, exc.reason, exc.message))
            if exc.reason in ("timeout", "camera_failed", "wrong_object"):  # not another grasp of it
                raise
            failures.append(exc)
            if exc.reason == "slipped":  # the object may have moved: re-estimate
                break
            continue
        _attempted(loop, run, AttemptRecord(n, grasp, "success", "held", width))
        run.grasp = grasp
        return
    if not failures:
        if tried == 0 and grasps:
            raise Abort("ik_failed", f"all {len(grasps)} grasps' approach or lift lines flip a wrist")
        raise Abort("no_feasible_grasp", "the plan held no grasp")
    raise failures[-1]


def _attempted(loop: Loop, run: RunRecord, record: AttemptRecord) -> None:
    """Note an attempt in the run's record (and the recorder's)."""
    run.attempts.append(record)
    loop.recorder.attempt(record)
