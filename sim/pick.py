"""A language pick-and-place episode in MuJoCo: `python -m sim pick --scene FILE --command "..." --out DIR`.

The library's `PickAndPlace` runs closed loop on the scene's `SimArm`, gripper and fixed camera with the
embedded estimator; nothing in the loop reads ground truth. Only after the run does `evaluate` (named so) read
the simulator's poses: which object the command meant (by its scene prompt), how high it was lifted, and its
ground-truth 9-DoF box next to the first estimate.

Writes `DIR/summary.json` (`success`, `lift_height_m`, `outcome`, `estimate` vs `ground_truth` 9-DoF in the
camera frame, timings, sim time), `DIR/overlay_0.png` (the estimate in green, ground truth in red) and, with
`video=True`, `DIR/episode.mp4` (OpenCV's mp4v writer; the fixed camera every 0.1 s of sim time).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import invert_T
from prompose_grasp.grasp import PalletPattern
from prompose_grasp.pipeline.cell import make_cell
from prompose_grasp.pipeline.outcome import PickOutcome, ProgressEvent
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.recorder import Recorder
from sim.bench_accounting import object_phrase
from sim.cell import SimCellConfig, place_targets_of
from sim.scene_file import build_scene, load_scene

__all__ = ["EpisodeResult", "evaluate_target", "place_targets_of", "run_episode", "target_name_for"]

logger = logging.getLogger(__name__)

#: A pick counts as lifted when the object's centre rose at least this much (half the planner's 10 cm lift).
MIN_LIFT_M = 0.05


@dataclass(frozen=True, eq=False)
class EpisodeResult:
    """One episode: the library's outcome and the evaluation against ground truth (after the run)."""

    outcome: PickOutcome
    summary: dict[str, Any]
    out_dir: Path | None
    #: the episode sampled at a fixed control rate (`sim.recording`), when run with `record`
    recording: Any = None


def _target_name(
    world, command_text: str, first_estimate_world: np.ndarray | None, start: dict[str, np.ndarray]
) -> str:
    """Evaluation only: the object the command meant: the longest scene prompt the object phrase contains;
    else, among the objects whose prompt's noun it names ("the brown carton" -> every carton), the one that
    moved most since the start (the one the loop acted on) when any moved more than 2 cm; else the object
    nearest the first estimate; with no estimate (the loop found nothing) and nothing moved, the first of
    those the noun names: any of them was the command's, and none was touched."""
    head = object_phrase(command_text)
    named = _named_in(world, head)
    if named:
        return max(named, key=lambda o: len(o.prompt)).name
    words = set(head.split())
    same = [o for o in world.objects if o.prompt and o.prompt.lower().split()[-1] in words]
    moved = {
        o.name: float(np.linalg.norm(world.T_world_obj(o.name)[:3, 3] - start[o.name][:3, 3])) for o in same
    }
    if moved and max(moved.values()) > 0.02:
        return max(moved, key=lambda n: moved[n])
    if first_estimate_world is None and same:
        return same[0].name
    if first_estimate_world is None:
        raise InvalidInputError(
            f"no scene object's prompt appears in {command_text!r} and nothing was estimated"
        )
    pool = same or list(world.objects)
    d = [np.linalg.norm(world.T_world_obj(o.name)[:3, 3] - first_estimate_world) for o in pool]
    return pool[int(np.argmin(d))].name


def _named_in(world, text: str) -> list:
    text = text.lower()
    return [o for o in world.objects if o.prompt and o.prompt.lower() in text]


def target_name_for(world, command_text: str) -> str:
    """Evaluation and oracle inputs only (ground truth): the object a command means before anything is
    estimated: the longest scene prompt it contains; else, among objects whose prompt's noun it names ("the
    brown carton" -> cartons), the one on top (highest centre), nearest the arm's base on a tie."""
    head = object_phrase(command_text)
    named = _named_in(world, head)
    if named:
        return max(named, key=lambda o: len(o.prompt)).name
    words = set(head.replace(",", " ").split())
    same = [o for o in world.objects if o.prompt and o.prompt.lower().split()[-1] in words]
    if not same:
        raise InvalidInputError(f"no scene object's prompt or noun appears in {command_text!r}")
    base = world.T_world_base[:3, 3]

    def key(o):
        t = world.T_world_obj(o.name)[:3, 3]
        return (round(float(t[2]), 2), -float(np.linalg.norm(t[:2] - base[:2])))

    return max(same, key=key).name


def evaluate_target(
    world, name: str, T_world_obj_start: np.ndarray, start: dict[str, np.ndarray] | None = None
) -> dict[str, Any]:
    """Evaluation only (ground truth): how far object `name` rose and moved since the start.

    With `start` ({object name: T_world_obj at the start}, every scene object) also `lifted_objects`: the
    names of every scene object whose centre rose at least `MIN_LIFT_M`, the named one or not (a claimed
    success that lifted only others lifted the wrong object)."""
    T_now = world.T_world_obj(name)
    ev: dict[str, Any] = {
        "object": name,
        "lift_height_m": float(T_now[2, 3] - T_world_obj_start[2, 3]),
        "start_world_m": T_world_obj_start[:3, 3].tolist(),
        "end_world_m": T_now[:3, 3].tolist(),
    }
    if start is not None:
        ev["lifted_objects"] = lifted_objects(world, start)
    return ev


def lifted_objects(world, start: dict[str, np.ndarray]) -> list[str]:
    """Evaluation only (ground truth): names of the scene objects whose centre rose >= `MIN_LIFT_M` since
    `start` ({name: T_world_obj}), in scene order."""
    return [
        o.name
        for o in world.objects
        if o.name in start and float(world.T_world_obj(o.name)[2, 3] - start[o.name][2, 3]) >= MIN_LIFT_M
    ]


def _evaluated_target(world, targets: list[str], start: dict[str, np.ndarray]) -> str:
    """Evaluation only: of the objects the command means (known by construction), the one that rose most
    (moved most on a tie within 1 mm: none rose), so a pick of either of two look-alikes is judged on the
    one picked."""
    unknown = [t for t in targets if t not in start]
    if unknown:
        raise InvalidInputError(f"targets {unknown} are not scene objects; known: {sorted(start)}")

    def key(n: str) -> tuple[float, float]:
        d = world.T_world_obj(n)[:3, 3] - start[n][:3, 3]
        return (round(float(d[2]), 3), float(np.linalg.norm(d)))

    return max(targets, key=key)


def _patterns(spec) -> dict[str, PalletPattern]:
    """{place target name: PalletPattern} from the scene file's `place_targets[].pattern`."""
    out = {}
    for p in spec.place_targets:
        if "pattern" in p:
            q = p["pattern"]
            rows, cols, layers = (int(q.get(k, d)) for k, d in (("rows", 3), ("cols", 3), ("layers", 2)))
            out[p["name"]] = PalletPattern(rows, cols, layers, float(q.get("gap_m", 0.01)))
    return out


def _pose_dict(pose) -> dict[str, Any]:
    return {
        "R": np.asarray(pose.R).tolist(),
        "t": np.asarray(pose.t).tolist(),
        "size": np.asarray(pose.size).tolist(),
    }


class _KeepFrames:
    """Passes captures through and keeps them (the overlay is drawn on the frame that was estimated)."""

    def __init__(self, camera):
        self.camera = camera
        self.frames: list[Any] = []

    def capture(self):
        frame = self.camera.capture()
        self.frames.append(frame)
        return frame


class _Recorder:
    """Renders the fixed camera every `every_s` of sim time (a step hook) for the episode video."""

    def __init__(self, world, camera: str, every_s: float = 0.1):
        self.world = world
        self.camera = camera
        self.every = max(1, round(every_s / float(world.model.opt.timestep)))
        self.frames: list[np.ndarray] = []
        self._n = 0

    def __call__(self, world) -> None:
        self._n += 1
        if self._n % self.every == 0:
            self.frames.append(world.render_clean(self.camera)[0])

    def write(self, path: Path, fps: float = 10.0) -> bool:
        if not self.frames:
            return False
        h, w = self.frames[0].shape[:2]
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        if not writer.isOpened():
            logger.warning("OpenCV has no mp4 writer here; no video written")
            return False
        for f in self.frames:
            writer.write(np.ascontiguousarray(f[..., ::-1]))
        writer.release()
        return True


def run_episode(
    scene: str | Path,
    command: str,
    out_dir: str | Path | None = None,
    seed: int | None = None,
    video: bool = False,
    camera: str | None = None,
    estimator: Any = None,
    config: PickConfig | None = None,
    on_event: Callable[[ProgressEvent], None] | None = None,
    camera_wrapper: Callable[[Any], Any] | None = None,
    estimator_wrapper: Callable[[Any, str], Any] | None = None,
    wrist: bool = True,
    targets: list[str] | None = None,
    recorder: Recorder | None = None,
    record: Any = None,
) -> EpisodeResult:
    """Build the scene, run the library's closed loop on it, then evaluate against ground truth.

    Args:
        scene: scene file; command: free text; out_dir: where to write (None: write nothing).
        seed: placement / appearance / sensor-noise seed (default: the file's).
        video: also write `episode.mp4`.
        camera: the fixed camera the loop observes with (default: the scene file's first fixed camera).
        estimator: default `ProMPose.default()`.
        config: `PickConfig`; on_event: progress callback.
        camera_wrapper: wraps the `SimCamera` (fault injection in tests: dropped frames, depth holes).
        estimator_wrapper: (world, camera name) -> the estimator the loop uses, built around `estimator`
            (benchmarks: `sim.bench_pick.OracleMaskEstimator`, named oracle).
        wrist: hand the scene's wrist camera (the first mounted one), if any, to the loop: it looks at the
            target from above before grasping.
        targets: evaluation only: the scene objects the command means, known by construction (a benchmark's
            plan; two look-alikes the words do not tell apart are both listed). The one that rose most is
            judged. Default: found from the command and the scene prompts (`_target_name`).
        recorder: records the episode (`prompose_grasp.viz.RerunRecorder`): the loop's stages, the arm and
            gripper, and (for the default estimator) its grounding and estimates. Not closed here.
        record: a `sim.recording.RecordConfig`: also sample the loop's run (front and wrist camera, joints,
            TCP, gripper, commanded actions) at its control rate into `EpisodeResult.recording`.

    The summary's `evaluation` also holds `lifted_objects` (every object that rose >= `MIN_LIFT_M`),
    `placed_objects` for place commands (every object that ended inside the place target and did not start
    there), `moved` (objects moved > 1 cm) and `scene_objects` (name, prompt, ground-truth size of each).
    """
    from prompose_grasp.perception.estimator import ProMPose

    t_wall = time.perf_counter()
    # the arguments and the scene file are checked before the estimator loads (seconds) or anything runs
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0):
        raise InvalidInputError(f"seed must be an integer >= 0 or None (the file's), got {seed!r}")
    if out_dir is not None and Path(out_dir).exists() and not Path(out_dir).is_dir():
        raise InvalidInputError(f"out_dir {str(out_dir)!r} exists and is not a folder")
    spec = load_scene(scene)
    estimator = estimator or ProMPose.default(recorder=recorder)
    if camera is None:
        fixed = [c["name"] for c in spec.cameras if "pose" in c]
        if not fixed:
            raise InvalidInputError(f"scene {scene} has no fixed camera to observe with")
        camera = fixed[0]
    if config is None and spec.extras.get("pipeline"):
        # The cell's settings of the loop (e.g. the tallest carton it handles), from the scene file.
        config = PickConfig(**dict(spec.extras["pipeline"]))
    world = build_scene(spec, seed=seed)
    with world:
        info = world.robot
        if info is None or info.gripper is None:
            raise InvalidInputError(f"scene {scene} has no robot with a gripper")
        rng = np.random.default_rng(seed)
        mounted = [c["name"] for c in spec.cameras if "mount" in c]
        cell = make_cell(
            SimCellConfig(world, camera, rng, mounted[0] if (wrist and mounted) else None, _patterns(spec))
        )
        arm = cell.arm  # a `SimArm`: its timing and contact forces go into the summary
        video_frames = _Recorder(world, camera) if video else None
        start = {o.name: world.T_world_obj(o.name) for o in world.objects}
        t0_sim = float(world.data.time)
        with cell:
            sim_cam = cell.camera
            keeper = _KeepFrames(camera_wrapper(sim_cam) if camera_wrapper is not None else sim_cam)
            loop_estimator = estimator if estimator_wrapper is None else estimator_wrapper(world, camera)
            # the loop observes through `keeper` (the frames it saw are kept for the summary's overlays)
            loop_cell = dataclasses.replace(cell, camera=keeper)
            pnp = PickAndPlace.for_cell(
                loop_cell, loop_estimator, config=config, on_event=on_event, recorder=recorder
            )
            if video_frames is not None:
                world.add_step_hook(video_frames)
            sampler = None
            if record is not None:
                from sim.recording import EpisodeRecorder, recorded_cameras

                sampler = EpisodeRecorder(world, arm, cell.gripper, recorded_cameras(world, camera), record)
                sampler.start()
            try:
                outcome = pnp.run(command)
            finally:
                recording = sampler.stop() if sampler is not None else None
            if video_frames is not None:
                world.remove_step_hook(video_frames)
            # Let the scene come to rest so a lost object has fallen before it is measured.
            world.step(int(0.5 / world.model.opt.timestep))
        # ----- evaluation (ground truth, after the run) -----
        first = outcome.estimates[0] if outcome.estimates else None
        first_world = None
        if first is not None:
            first_world = (
                world.T_world_base @ np.append(first.pose.transformed(outcome.T_base_cams[0]).t, 1.0)
            )[:3]
        if targets:
            name = _evaluated_target(world, list(targets), start)
        else:
            name = _target_name(world, command, first_world, start)
        ev = evaluate_target(world, name, start[name], start)
        sizes = {g.name: g.size_m for g in world.ground_truth(camera)}
        ev["scene_objects"] = [
            {
                "name": o.name,
                "prompt": o.prompt,
                "size_m": [round(float(v), 4) for v in sizes[o.name]] if o.name in sizes else None,
            }
            for o in world.objects
        ]
        # Which objects the run moved (> 1 cm): a reported hold whose target did not rise held a neighbour.
        ev["moved"] = {
            o.name: {
                "lift_m": round(float(world.T_world_obj(o.name)[2, 3] - start[o.name][2, 3]), 4),
                "moved_m": round(
                    float(np.linalg.norm(world.T_world_obj(o.name)[:3, 3] - start[o.name][:3, 3])), 4
                ),
            }
            for o in world.objects
            if np.linalg.norm(world.T_world_obj(o.name)[:3, 3] - start[o.name][:3, 3]) > 0.01
        }
        lifted = ev["lift_height_m"] >= MIN_LIFT_M
        gt_cam = None
        overlays = []
        if first is not None:
            T_cam_world = invert_T(world.T_world_base @ outcome.T_base_cams[0])
            from prompose_grasp.geometry import Pose9D

            T_cam_obj = T_cam_world @ start[name]
            size = next(g.size_m for g in world.ground_truth(camera) if g.name == name)
            gt_cam = Pose9D(T_cam_obj[:3, :3], T_cam_obj[:3, 3], np.asarray(size, dtype=np.float64))
        action = outcome.command.action if outcome.command is not None else None
        success = outcome.success and (lifted if action == "pick" else True)
        inside_fn = None  # evaluation of a place: world point -> inside the place target
        if (
            action in ("place", "stack")
            and outcome.command is not None
            and outcome.command.target == "object"
        ):
            holders = _named_in(world, outcome.command.target_prompt)
            if holders:
                holder = max(holders, key=lambda o: len(o.prompt))
                T_h_inv = invert_T(world.T_world_obj(holder.name))
                size_h = next(g.size_m for g in world.ground_truth(camera) if g.name == holder.name)

                def inside_fn(p_world, T_h_inv=T_h_inv, size_h=size_h) -> bool:
                    p = T_h_inv @ np.append(p_world, 1.0)  # holder frame: +y up
                    return bool(
                        abs(p[0]) <= size_h[0] / 2 + 0.01
                        and abs(p[2]) <= size_h[2] / 2 + 0.01
                        and -size_h[1] / 2 < p[1] < size_h[1] / 2 + 0.3
                    )

                ev["place_object"] = holder.name
            else:
                ev["inside_target"] = None  # the place phrase names no scene object: not judged
                success = False
        elif action in ("place", "stack") and outcome.command is not None:
            support = next(
                (s for s in world.place_targets.values() if s.kind == outcome.command.target), None
            )
            if support is not None:
                T_s_inv = invert_T(support.T_world_surface)

                def inside_fn(p_world, T_s_inv=T_s_inv, half=support.half_extents_xy_m) -> bool:
                    p = T_s_inv @ np.append(p_world, 1.0)
                    return bool(np.all(np.abs(p[:2]) <= half) and -0.01 < p[2] < 0.3)

        if inside_fn is not None:
            inside = inside_fn(np.asarray(ev["end_world_m"]))
            ev["inside_target"] = inside
            success = outcome.success and inside
            # Every object that ended inside the place target and did not start there (the holder excluded):
            # a claimed place whose target is not among them put another object there.
            ev["placed_objects"] = [
                o.name
                for o in world.objects
                if o.name != ev.get("place_object")
                and inside_fn(world.T_world_obj(o.name)[:3, 3])
                and not inside_fn(start[o.name][:3, 3])
            ]
        timing = arm.timing()
        summary = {
            "scene": str(scene),
            "seed": seed,
            "command": command,
            "success": bool(success),
            "lift_height_m": ev["lift_height_m"],
            "outcome": outcome.to_dict(),
            "evaluation": ev,
            "estimate": None if first is None else _pose_dict(first.pose),
            "ground_truth": None if gt_cam is None else _pose_dict(gt_cam),
            "estimate_centre_error_m": None
            if first is None or gt_cam is None
            else float(np.linalg.norm(np.asarray(first.pose.t) - np.asarray(gt_cam.t))),
            "frame": "camera (OpenCV) of the first observation",
            "timings_s": {**outcome.timings_s, "episode_wall": time.perf_counter() - t_wall},
            "sim_time_s": float(world.data.time) - t0_sim,
            "arm_sim_time_s": timing.sim_time_s,
            "arm_wall_time_s": timing.wall_time_s,
            # the largest net contact force on the robot during its motions (`sim.arm`'s protective stop)
            "arm_max_external_force_n": arm.max_external_force_n,
        }
        if out_dir is not None:
            out = Path(out_dir)
            out.mkdir(parents=True, exist_ok=True)
            if first is not None and keeper.frames:
                from prompose_grasp.perception.overlay import ESTIMATE_RGB, GROUND_TRUTH_RGB, draw_poses

                k_frame = min(len(keeper.frames), pnp.config.observe_frames) - 1
                frame = keeper.frames[k_frame]
                poses = [first.pose] + ([gt_cam] if gt_cam is not None else [])
                colors = [ESTIMATE_RGB] + ([GROUND_TRUTH_RGB] if gt_cam is not None else [])
                labels = ["estimate", "ground truth"][: len(poses)]
                drawn = draw_poses(frame.rgb, frame.intrinsics, poses, colors, labels)
                cv2.imwrite(str(out / "overlay_0.png"), drawn[..., ::-1])
                overlays.append("overlay_0.png")
            summary["overlays"] = overlays
            if video_frames is not None:
                summary["video"] = "episode.mp4" if video_frames.write(out / "episode.mp4") else None
            (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return EpisodeResult(outcome, summary, None if out_dir is None else Path(out_dir), recording)
