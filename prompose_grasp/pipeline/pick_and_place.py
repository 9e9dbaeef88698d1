"""The closed loop: command -> observe -> estimate -> plan grasps -> execute -> verify -> retry.

```
pnp = PickAndPlace(arm, gripper, camera, ProMPose.default(), robot, "parallel_jaw",
                   place_targets={"bin": PlaceTarget("bin", T_base_bin, [0.13, 0.10], 0.10)})
outcome = pnp.run("put the red mug in the bin")      # PickOutcome; outcome.reason, outcome.timings_s
```

Nothing here reads ground truth: the target is whatever the estimator grounds from the camera frames, the
grasp is planned on that estimate and the observed points, and success is judged from the gripper (jaws
stopped on something / suction contact) and a re-observation (the object is no longer where it stood).

Every expected failure ends the run with a typed reason (`PickOutcome.reason`) instead of an exception:

| reason | when |
|---|---|
| camera_failed | the camera raised `CameraError` on every retry, or its frames carry no `T_base_cam` |
| not_found | the command names nothing understood, or the estimator finds no object matching the prompt |
| no_feasible_grasp | every grasp (or place) candidate was rejected for collisions, stroke, support, ... |
| ik_failed | the candidates failed mostly on reach, or the arm refused every motion (validator / IK) |
| collision | every feasible grasp's approach path collides with the observed scene |
| slipped | the gripper closed on nothing or lost the object, on every attempt |
| timeout | `PickConfig.timeout_s` passed (checked between stages; a running move is never cut) |

Every motion goes through the `Arm`'s own methods, which validate it (`CommandValidator`) before moving; a
refused command raises in the arm and leaves it still, and the loop counts it as a failed attempt.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import (
    CameraError,
    InvalidInputError,
    NoFeasibleGrasp,
    NoFeasibleMotion,
    NoFeasiblePlace,
    ObjectNotFoundError,
    UnreachableError,
    UnsafeCommandError,
)
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.se3 import transform_points
from prompose_grasp.grasp import (
    GraspConfig,
    ObjectModel,
    PlaceTarget,
    Plane,
    check_path,
    get_gripper,
    plan_grasps,
    plan_pick_place,
    plan_place,
)
from prompose_grasp.grasp.planner import build_scene
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser
from prompose_grasp.pipeline.outcome import AttemptRecord, PickOutcome, ProgressEvent
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["PickAndPlace", "PickConfig"]

logger = logging.getLogger(__name__)

_STAGE_KEYS = ("observe", "estimate", "plan", "execute", "verify")


@dataclass(frozen=True)
class PickConfig:
    """Settings of the closed loop.

    Attributes:
        max_estimates: observe-estimate-plan rounds (a slip or a moved object starts a new round).
        grasps_per_estimate: grasps of one plan tried (best first) before re-estimating.
        camera_retries: captures tried per observation before "camera_failed" (dropped frames are retried).
        observe_frames: frames per observation; more than one runs the estimator's tracker over them and
            keeps the last (temporally refined) estimate.
        timeout_s: wall-time budget of a run [s].
        joint_speed_rad_s, joint_accel_rad_s2: free moves to the pre-grasp [rad/s, rad/s^2].
        linear_speed_m_s, linear_accel_m_s2: approach and lift lines [m/s, m/s^2].
        grip_force_n: jaw force per finger / suction holding force [N].
        min_jaw_width_m: jaws closed narrower than this held nothing [m] (the 2F-85 class stops at 0).
        moved_min_m: on re-observation the object counts as picked when its estimate moved more than this
            (or is no longer seen where it stood) [m]; half the default 10 cm lift.
        max_scene_points: observed points handed to the collision scene (evenly thinned) [-].
        reobserve: re-observe after the lift to confirm the pick.
        grasp: `GraspConfig` of the planner.
    """

    max_estimates: int = 3
    grasps_per_estimate: int = 3
    camera_retries: int = 3
    observe_frames: int = 1
    timeout_s: float = 300.0
    joint_speed_rad_s: float = 1.0
    joint_accel_rad_s2: float = 2.0
    linear_speed_m_s: float = 0.2
    linear_accel_m_s2: float = 1.0
    grip_force_n: float = 60.0
    min_jaw_width_m: float = 0.004
    moved_min_m: float = 0.05
    max_scene_points: int = 40000
    reobserve: bool = True
    grasp: GraspConfig | None = None

    def __post_init__(self) -> None:
        ints = (
            "max_estimates",
            "grasps_per_estimate",
            "camera_retries",
            "observe_frames",
            "max_scene_points",
        )
        for name in ints:
            if int(getattr(self, name)) < 1:
                raise InvalidInputError(f"PickConfig.{name} must be >= 1, got {getattr(self, name)}")
        floats = (
            "timeout_s",
            "joint_speed_rad_s",
            "joint_accel_rad_s2",
            "linear_speed_m_s",
            "linear_accel_m_s2",
            "grip_force_n",
            "moved_min_m",
        )
        for name in floats:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"PickConfig.{name} must be finite and > 0, got {v}")


class _Abort(Exception):
    """Ends a run with a typed reason (internal; never escapes `run`)."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason
        self.message = message


@dataclass(frozen=True, eq=False)
class _Observation:
    frame: RGBDFrame
    estimate: Any
    target: ObjectModel
    support: Plane | None
    points_base: np.ndarray


class PickAndPlace:
    """Closed-loop language pick-and-place on any `Arm`, `Gripper` and `RGBDCamera`.

    Args:
        arm: the arm (validates its own commands).
        gripper: the gripper matching `gripper_kind`.
        camera: a fixed (or any calibrated) camera whose frames carry `T_base_cam`.
        estimator: `ProMPose` (or anything with `estimate(frame, prompt)` and `track(frames, prompt)`).
        robot_model: the arm's `RobotModel` with the gripper's tcp offset.
        gripper_kind: "parallel_jaw" or "suction".
        place_targets: {kind: PlaceTarget} for place commands ("bin", "table", "pallet", "conveyor").
        config: `PickConfig`.
        on_event: called with each `ProgressEvent` (a live display).
        parser: the command parser (default: `CommandParser()`, MiniLM loaded on first use).
    """

    def __init__(
        self,
        arm: Any,
        gripper: Any,
        camera: Any,
        estimator: Any,
        robot_model: Any,
        gripper_kind: str = "parallel_jaw",
        place_targets: Mapping[str, PlaceTarget] | None = None,
        config: PickConfig | None = None,
        on_event: Callable[[ProgressEvent], None] | None = None,
        parser: CommandParser | None = None,
    ):
        self.arm = arm
        self.gripper = gripper
        self.camera = camera
        self.estimator = estimator
        self.robot = robot_model
        self.gripper_geometry = get_gripper(gripper_kind)
        self.gripper_kind = gripper_kind
        self.place_targets = dict(place_targets or {})
        for kind, target in self.place_targets.items():
            if not isinstance(target, PlaceTarget):
                raise InvalidInputError(f"place_targets[{kind!r}] must be a PlaceTarget, got {type(target)}")
        self.config = config or PickConfig()
        self.on_event = on_event
        self.parser = parser

    # ------------------------------------------------------------------------------------------------ run
    def run(self, command: str | Command) -> PickOutcome:
        """Run one command to its end. Returns a `PickOutcome`; expected failures are reasons, not raises."""
        t_start = time.perf_counter()
        timings = dict.fromkeys(_STAGE_KEYS, 0.0)
        state: dict[str, Any] = {
            "estimates": [],
            "T_base_cams": [],
            "attempts": [],
            "grasp": None,
            "place": None,
        }
        cmd: Command | None = None

        def finish(reason: str, message: str) -> PickOutcome:
            timings["total"] = time.perf_counter() - t_start
            self._emit("done", f"{reason}: {message}", 1.0, len(state["attempts"]))
            logger.info("pick run ended: %s (%s)", reason, message)
            return PickOutcome(
                reason=reason,
                message=message,
                command=cmd,
                estimates=tuple(state["estimates"]),
                T_base_cams=tuple(state["T_base_cams"]),
                attempts=tuple(state["attempts"]),
                grasp=state["grasp"],
                place=state["place"],
                timings_s=dict(timings),
            )

        try:
            cmd = self._parse(command)
            target = None
            if cmd.action in ("place", "stack"):
                target = self.place_targets.get(cmd.target or "")
                if target is None:
                    known = ", ".join(sorted(self.place_targets)) or "none configured"
                    raise _Abort("not_found", f"no place target {cmd.target!r} (known: {known})")
            last = _Abort("not_found", "no attempt was made")
            q_home = np.asarray(self.arm.joint_positions(), dtype=np.float64)
            for round_ in range(self.config.max_estimates):
                self._check_time(t_start)
                obs = self._observe_and_estimate(cmd.object_prompt, timings, state, round_)
                try:
                    self._attempt_round(obs, cmd, target, timings, state, t_start)
                    return finish("success", self._success_message(cmd, state))
                except _Abort as exc:
                    if exc.reason in ("timeout", "camera_failed"):
                        raise
                    last = exc
                    logger.info("round %d failed: %s (%s)", round_ + 1, exc.reason, exc.message)
                    self._go_home(q_home)
            raise last
        except _Abort as exc:
            return finish(exc.reason, exc.message)

    # ------------------------------------------------------------------------------------------- stages
    def _emit(self, stage: str, message: str, fraction: float, attempt: int = 0) -> None:
        if self.on_event is not None:
            self.on_event(ProgressEvent(stage, message, min(max(fraction, 0.0), 1.0), attempt))

    def _check_time(self, t_start: float) -> None:
        elapsed = time.perf_counter() - t_start
        if elapsed > self.config.timeout_s:
            raise _Abort("timeout", f"{elapsed:.1f} s exceeds the {self.config.timeout_s:.1f} s budget")

    def _parse(self, command: str | Command) -> Command:
        self._emit("parse", f"parsing {command!r}", 0.0)
        if isinstance(command, Command):
            return command
        if self.parser is None:
            self.parser = CommandParser()
        try:
            return self.parser.parse(command)
        except CommandNotUnderstood as exc:
            raise _Abort("not_found", f"command not understood: {exc}") from None
        except InvalidInputError as exc:
            raise _Abort("not_found", f"command not understood: {exc}") from None

    def _capture(self) -> RGBDFrame:
        errors = []
        for _ in range(self.config.camera_retries):
            try:
                frame = self.camera.capture()
            except CameraError as exc:  # a dropped frame: try again
                errors.append(str(exc))
                logger.warning("camera capture failed (%s); retrying", exc)
                continue
            if not isinstance(frame, RGBDFrame):
                raise _Abort("camera_failed", f"the camera returned {type(frame).__name__}, not an RGBDFrame")
            if frame.T_base_cam is None:
                raise _Abort("camera_failed", "the frame has no T_base_cam: calibrate the camera to the base")
            return frame
        raise _Abort(
            "camera_failed",
            f"{self.config.camera_retries} captures failed; last: {errors[-1] if errors else '?'}",
        )

    def _estimate(self, prompt: str, timings: dict[str, float]) -> tuple[RGBDFrame, Any]:
        t0 = time.perf_counter()
        frames = [self._capture() for _ in range(self.config.observe_frames)]
        timings["observe"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            if len(frames) == 1:
                est = self.estimator.estimate(frames[0], prompt)
            else:
                est = list(self.estimator.track(frames, prompt))[-1]
        except ObjectNotFoundError as exc:
            raise _Abort("not_found", str(exc)) from None
        except InvalidInputError as exc:  # e.g. a depth image without a single reading
            raise _Abort("not_found", f"the frame cannot be used: {exc}") from None
        finally:
            timings["estimate"] += time.perf_counter() - t0
        return frames[-1], est

    def _observe_and_estimate(
        self, prompt: str, timings: dict[str, float], state: dict[str, Any], round_: int
    ) -> _Observation:
        frac = round_ / self.config.max_estimates
        self._emit("observe", f"observing ({self.config.observe_frames} frame(s))", 0.05 + 0.9 * frac)
        frame, est = self._estimate(prompt, timings)
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        state["estimates"].append(est)
        state["T_base_cams"].append(T_base_cam)
        pose_base = est.pose.transformed(T_base_cam)
        self._emit(
            "estimate",
            f"{prompt!r}: {est.prior.name} at {np.round(pose_base.t, 3).tolist()} m, "
            f"size {np.round(pose_base.size, 3).tolist()} m",
            0.15 + 0.9 * frac,
        )
        mesh = est.mesh_cam.copy()
        mesh.apply_transform(T_base_cam)
        target = ObjectModel(
            "target", pose_base, mesh=mesh, family=est.prior.name, symmetry=est.prior.symmetry
        )
        support = None
        if est.support_plane is not None:
            support = Plane.from_camera(est.support_plane.normal_cam, est.support_plane.offset_m, T_base_cam)
        points = transform_points(T_base_cam, back_project(frame.depth_m, frame.intrinsics))
        stride = max(1, len(points) // self.config.max_scene_points)
        return _Observation(frame, est, target, support, points[::stride])

    def _plan(
        self, obs: _Observation, q_now: np.ndarray, timings: dict[str, float]
    ) -> tuple[Any, CollisionScene]:
        t0 = time.perf_counter()
        cfg = self.config.grasp or GraspConfig()
        try:
            scene = build_scene(
                obs.target, self.robot, self.gripper_geometry, (), obs.support, obs.points_base, q_now, cfg
            )
            plan = plan_grasps(
                obs.target, self.robot, self.gripper_geometry, q_seed=q_now, config=cfg, scene=scene
            )
        except NoFeasibleGrasp as exc:
            reach = sum(v for k, v in exc.rejected.items() if k.startswith("ik"))
            reason = "ik_failed" if reach * 2 >= max(1, sum(exc.rejected.values())) else "no_feasible_grasp"
            raise _Abort(reason, str(exc)) from None
        finally:
            timings["plan"] += time.perf_counter() - t0
        return plan, scene

    def _attempt_round(
        self,
        obs: _Observation,
        cmd: Command,
        place_target: PlaceTarget | None,
        timings: dict[str, float],
        state: dict[str, Any],
        t_start: float,
    ) -> None:
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        self._emit("plan", "planning grasps", 0.3)
        plan, scene = self._plan(obs, q_now, timings)
        failures: list[_Abort] = []
        for i, grasp in enumerate(plan.grasps[: self.config.grasps_per_estimate]):
            self._check_time(t_start)
            n = len(state["attempts"]) + 1
            self._emit(
                "execute",
                f"grasp {i + 1}/{len(plan)} ({grasp.method}, quality {grasp.quality:.2f})",
                0.45,
                n,
            )
            try:
                if place_target is None:
                    width = self._pick(grasp, scene, timings)
                    self._reobserve(cmd.object_prompt, obs.target, timings, state)
                else:
                    width = self._pick_place(obs, grasp, place_target, scene, timings, state, n)
            except _Abort as exc:
                state["attempts"].append(AttemptRecord(n, grasp, exc.reason, exc.message))
                if exc.reason in ("timeout", "camera_failed"):
                    raise
                failures.append(exc)
                if exc.reason == "slipped":  # the object may have moved: re-estimate
                    break
                continue
            state["attempts"].append(AttemptRecord(n, grasp, "success", "held", width))
            state["grasp"] = grasp
            return
        if not failures:
            raise _Abort("no_feasible_grasp", "the plan held no grasp")
        raise failures[-1]

    # ---------------------------------------------------------------------------------------- execution
    def _safe(self, what: str, fn: Callable[[], Any]) -> Any:
        """Run one arm command; a refusal by the validator or IK is an "ik_failed" attempt."""
        try:
            return fn()
        except UnreachableError as exc:
            raise _Abort("ik_failed", f"{what}: {exc}") from None
        except UnsafeCommandError as exc:
            raise _Abort("ik_failed", f"{what} refused by the validator: {exc}") from None

    def _pick(self, grasp: Any, scene: CollisionScene, timings: dict[str, float]) -> float:
        cfg = self.config
        t0 = time.perf_counter()
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        ik = self.robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
        if not ik.success:
            timings["execute"] += time.perf_counter() - t0
            raise _Abort("ik_failed", f"pre-grasp: {ik.message}")
        _, hit = check_path(
            self.robot, scene, np.array([q_now, ik.q]), self.gripper_geometry, grasp.opening_m, True
        )
        if hit is not None:
            timings["execute"] += time.perf_counter() - t0
            raise _Abort("collision", f"path to the pre-grasp hits {hit.name}: {hit.reason}")
        try:
            self.gripper.open()
            self._safe(
                "to pre-grasp",
                lambda: self.arm.move_joints(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2),
            )
            self._safe(
                "approach",
                lambda: self.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2),
            )
            self.gripper.close(cfg.grip_force_n)
            self._safe(
                "lift",
                lambda: self.arm.move_linear(
                    grasp.T_base_retreat, cfg.linear_speed_m_s, cfg.linear_accel_m_s2
                ),
            )
        finally:
            timings["execute"] += time.perf_counter() - t0
        return self._verify_held(grasp, timings)

    def _verify_held(self, grasp: Any, timings: dict[str, float]) -> float:
        t0 = time.perf_counter()
        try:
            self._emit("verify", "checking the grip", 0.7)
            width = float(self.gripper.width())
            held = bool(self.gripper.grasp_detected())
            if self.gripper_kind == "parallel_jaw":
                held = held and width >= self.config.min_jaw_width_m
            if not held:
                self._release_and_back_off(grasp)
                raise _Abort("slipped", f"nothing held after closing (jaw width {1e3 * width:.1f} mm)")
        finally:
            timings["verify"] += time.perf_counter() - t0
        return width

    def _go_home(self, q_home: np.ndarray) -> None:
        """Back to where the run started, out of the camera's view, before observing again."""
        cfg = self.config
        try:
            self.arm.move_joints(q_home, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.warning("could not return to the start configuration: %s", exc)

    def _release_and_back_off(self, grasp: Any) -> None:
        self.gripper.open()
        cfg = self.config
        try:
            self.arm.move_linear(grasp.T_base_retreat, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.warning("could not back off after a failed grasp: %s", exc)

    def _reobserve(
        self, prompt: str, before: ObjectModel, timings: dict[str, float], state: dict[str, Any]
    ) -> None:
        """After the lift: the object must no longer be seen where it stood."""
        if not self.config.reobserve:
            return
        self._emit("verify", "re-observing", 0.8)
        try:
            frame, est = self._estimate(prompt, timings)
        except _Abort as exc:
            if exc.reason == "not_found":  # lifted out of view or hidden by the gripper: not where it stood
                return
            raise
        t0 = time.perf_counter()
        pose_base = est.pose.transformed(np.asarray(frame.T_base_cam, dtype=np.float64))
        moved = float(np.linalg.norm(pose_base.t - before.pose.t))
        timings["verify"] += time.perf_counter() - t0
        state["estimates"].append(est)
        state["T_base_cams"].append(np.asarray(frame.T_base_cam, dtype=np.float64))
        if moved < self.config.moved_min_m:
            self.gripper.open()
            raise _Abort("slipped", f"the object is still where it stood (moved {1e3 * moved:.0f} mm)")

    def _pick_place(
        self,
        obs: _Observation,
        grasp: Any,
        target: PlaceTarget,
        scene: CollisionScene,
        timings: dict[str, float],
        state: dict[str, Any],
        attempt: int,
    ) -> float:
        cfg = self.config
        t0 = time.perf_counter()
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        try:
            place = plan_place(
                obs.target,
                grasp,
                target,
                self.robot,
                self.gripper_geometry,
                points_base=obs.points_base,
                q_seed=grasp.q,
            )
            scene_held = CollisionScene((), obs.support, obs.points_base, None)
            motion = plan_pick_place(
                self.robot, grasp, place, obs.target, scene, scene_held, self.gripper_geometry, q_now
            )
        except NoFeasiblePlace as exc:
            raise _Abort("no_feasible_grasp", str(exc)) from None
        except NoFeasibleMotion as exc:
            reason = "ik_failed" if "IK" in exc.reason else "collision"
            raise _Abort(reason, str(exc)) from None
        finally:
            timings["plan"] += time.perf_counter() - t0
        state["place"] = place
        t0 = time.perf_counter()
        width = 0.0
        try:
            self.gripper.open()
            for seg in motion.segments:
                self._emit("place" if seg.holding else "execute", f"segment {seg.name}", 0.5, attempt)
                self._safe(seg.name, functools.partial(self.arm.follow, seg.trajectory))
                if seg.name == "approach":
                    self.gripper.close(cfg.grip_force_n)
                elif seg.name == "lift":
                    timings["execute"] += time.perf_counter() - t0
                    width = self._verify_held(grasp, timings)
                    t0 = time.perf_counter()
                elif seg.name == "descend":
                    if not self.gripper.grasp_detected():
                        self.gripper.open()
                        raise _Abort("slipped", "the object was lost during the transfer")
                    self.gripper.open()
        finally:
            timings["execute"] += time.perf_counter() - t0
        return width

    def _success_message(self, cmd: Command, state: dict[str, Any]) -> str:
        n = len(state["attempts"])
        what = (
            f"picked {cmd.object_prompt!r}"
            if cmd.action == "pick"
            else f"placed {cmd.object_prompt!r} on the {cmd.target}"
        )
        return f"{what} after {n} attempt(s)"
