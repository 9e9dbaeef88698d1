"""The closed loop: parse -> observe -> ground -> plan -> execute -> verify, round after round.

```
pnp = PickAndPlace(arm, gripper, camera, ProMPose.default(), robot, "parallel_jaw",
                   place_targets={"bin": PlaceTarget("bin", T_base_bin, [0.13, 0.10], 0.10)})
outcome = pnp.run("put the red mug in the bin")      # PickOutcome; outcome.reason, outcome.timings_s
with make_cell(config) as cell:                       # the same on a cell from the factory (`cell`)
    outcome = PickAndPlace.for_cell(cell, ProMPose.default()).run("put the red mug in the bin")
```

Nothing here reads ground truth: the target is whatever the estimator grounds from the camera frames, the
grasp is planned on that estimate and the observed points, and success is judged from the gripper (jaws
stopped on something / suction contact) and a re-observation (the object is no longer where it stood).

Each stage is a module of this package, working on the `Loop` (the cell, estimator, settings) and the run's
`RunRecord`:

| stage | module | what |
|---|---|---|
| parse | `command` | the command text -> `Command` (action, object prompt, place target) |
| observe | `observe`, `candidates` | frames without the robot's depth; the candidates, in the order tried |
| ground | `ground` | a place phrase naming no fixture -> a `PlaceTarget` (`grasp.place_targets`) |
| plan | `plan`, `wrist_look` | grasps on the first candidate that has one; a closer look from the wrist |
| execute | `attempt`, `execute`, `hand` | grasps refined (`grasp.refine`), tried best first; pick, place |
| verify | `verify`, `wrong_object` | held? lifted? the object named? (fails closed) |
| stop | `faults` | the stop path after a device fault |

Around them: `cell` (the devices, `make_cell`), `seams` (the estimator protocols), `loop` (what every stage
works with), `record` (the run's record, `Abort`, stage timing), `config` (`PickConfig`).

Every expected failure ends the run with a typed reason (`PickOutcome.reason`) instead of an exception:

| reason | when |
|---|---|
| not_understood | the command text could not be parsed (the message says what was understood, and examples) |
| camera_failed | the camera raised `CameraError` on every retry, or its frames carry no `T_base_cam` |
| not_found | the estimator finds no object matching the prompt (or no place target the command names) |
| no_feasible_grasp | every grasp (or place) candidate was rejected for collisions, stroke, support, ... |
| ik_failed | the candidates failed mostly on reach, or the arm refused every motion (validator / IK) |
| collision | every feasible grasp's approach path collides with the observed scene |
| slipped | the gripper closed on nothing or lost the object, on every attempt |
| timeout | `PickConfig.timeout_s` passed (checked between stages; a running move is never cut) |
| ambiguous | several objects fit the prompt about equally well and the command names one: nothing moved |
| wrong_object | after the lift a standing object fits the prompt clearly better: the held one was put back |
| protective_stop | the arm (or its controller) raised `ProtectiveStopError` (a collision, a force limit) |
| emergency_stop | the arm raised `EmergencyStopError` (an e-stop) |
| connection_lost | a device raised `ConnectionLostError` (its link dropped) |
| motion_failed | the arm raised `MotionFailedError` (the controller refused or did not finish a move) |
| gripper_failed | the gripper raised `GripperError` (it refused or did not finish a command) |

A device fault ends the run at once, after the stop path (`faults.stop_after_fault`).

Which object: the estimator's candidates for the prompt whose grounding score is within `candidate_ratio` of
the best are all "the object" (identical cartons on a pallet); with `candidate_order="top_first"` (default)
they are tried from the highest top down (what lies on top of a pile first), with `"score"` (a tabletop of
different things, where a 90 % candidate is often another object) best match first; any already at the place
target is skipped, and the first with a feasible grasp is picked. When the estimator says several objects fit
the prompt about equally well (`Estimate.contenders` >= 2, or `AmbiguousObjectError`), a command naming one
object with `candidate_order="score"` ends "ambiguous" before anything moves (`describe.describe_contenders`
says which could be meant); a plural command and a `"top_first"` stack take any of them. `contenders` 0 (none
fits the words) is "not_found"; -1 (not judged) changes nothing.

Verification: the jaws must have stopped on something (the gripper's own detection) no narrower than
`min_jaw_width_m`, or half the planned contact width for a thinner part (a cup's 2 mm wall); after a pick the

A plural command ("move the cartons to the conveyor") repeats pick-and-place until no such object
is left (or `max_objects`). A place target that names no fixture of the cell ("in the white bowl", "on the tea
box") is grounded in the image like the object: the named object's estimated box becomes a bin (into) or a
surface (onto).

Every motion goes through the `Arm`'s own methods, which validate it (`CommandValidator`) before moving; a
refused command raises in the arm and leaves it still, and the loop counts it as a failed attempt.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Mapping

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp import PlaceTarget, get_gripper
from prompose_grasp.grasp.grippers import GripperGeometry
from prompose_grasp.pipeline.attempt import try_grasps
from prompose_grasp.pipeline.candidates import observe_candidates
from prompose_grasp.pipeline.cell import Cell
from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser
from prompose_grasp.pipeline.config import PickConfig
from prompose_grasp.pipeline.faults import DEVICE_FAULTS, fault_reason, stop_after_fault
from prompose_grasp.pipeline.ground import ground_place_target
from prompose_grasp.pipeline.hand import go_home
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.outcome import PickOutcome, ProgressEvent, Reason
from prompose_grasp.pipeline.plan import choose_and_plan, plan
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.recording import ObservedArm, ObservedGripper
from prompose_grasp.pipeline.seams import Estimator
from prompose_grasp.pipeline.wrist_look import wrist_look
from prompose_grasp.recorder import Recorder
from prompose_grasp.robot.interfaces import Arm, Gripper, RGBDCamera
from prompose_grasp.robot.model import RobotModel
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

__all__ = ["PickAndPlace", "PickConfig"]

logger = logging.getLogger(__name__)


class PickAndPlace:
    """Closed-loop language pick-and-place on any `Arm`, `Gripper` and `RGBDCamera`.

    Args:
        arm: the arm (validates its own commands).
        gripper: the gripper matching `gripper_kind`. A parallel-jaw gripper with an `open_to(width_m)`
            method opens only as wide as each grasp needs (`PickConfig.open_margin_m`); otherwise fully.
        camera: a fixed (or any calibrated) camera whose frames carry `T_base_cam`.
        estimator: `ProMPose` (or anything with `estimate(frame, prompt)` and `track(frames, prompt)`;
            `estimate_all(frame, prompt, max_objects=, min_score_ratio=)` when present gives the alternative
            candidates).
        robot_model: the arm's `RobotModel` with the gripper's tcp offset.
        gripper_kind: "parallel_jaw" or "suction".
        place_targets: {kind: PlaceTarget} fixtures for place commands ("bin", "table", "pallet", "conveyor").
        config: `PickConfig`.
        on_event: called with each `ProgressEvent` (a live display).
        parser: the command parser (default: `CommandParser()`, MiniLM loaded on first use).
        wrist_camera: a camera on the arm (frames with `T_base_cam` at capture), or None: the target is
            observed again from above it before the grasp (`PickConfig.wrist_look_m`).
        validator: the `CommandValidator` every planned motion is checked against before the first of its
            moves is sent (default: the arm's own `validator` when it has one, else one for `robot_model`), so
            a plan the arm would refuse halfway is dropped before anything moves.
        recorder: a `prompose_grasp.recorder.Recorder` (e.g. `prompose_grasp.viz.RerunRecorder`) that each
            run records into, one episode per `run`: frames, candidates, grasps, the arm's commands with
            its joints measured while they ran, the gripper, the outcome. None: nothing is recorded and no
            device is wrapped.

    `PickAndPlace.for_cell(cell, estimator, ...)` builds the same loop from a `Cell` (`pipeline.make_cell`).
    """

    def __init__(
        self,
        arm: Arm,
        gripper: Gripper,
        camera: RGBDCamera,
        estimator: Estimator,
        robot_model: RobotModel,
        gripper_kind: str = "parallel_jaw",
        place_targets: Mapping[str, PlaceTarget] | None = None,
        config: PickConfig | None = None,
        on_event: Callable[[ProgressEvent], None] | None = None,
        parser: CommandParser | None = None,
        validator: CommandValidator | None = None,
        wrist_camera: RGBDCamera | None = None,
        recorder: Recorder | None = None,
    ):
        geometry = get_gripper(gripper_kind)
        cell = Cell(arm, gripper, camera, robot_model, geometry, dict(place_targets or {}), wrist_camera)
        self._connect(cell, estimator, config, on_event, parser, validator, recorder)

    @classmethod
    def for_cell(
        cls,
        cell: Cell,
        estimator: Estimator,
        config: PickConfig | None = None,
        on_event: Callable[[ProgressEvent], None] | None = None,
        parser: CommandParser | None = None,
        validator: CommandValidator | None = None,
        recorder: Recorder | None = None,
    ) -> PickAndPlace:
        """The loop on a `Cell` (the arguments as for the constructor)."""
        pnp = cls.__new__(cls)
        pnp._connect(cell, estimator, config, on_event, parser, validator, recorder)
        return pnp

    def _connect(
        self,
        cell: Cell,
        estimator: Estimator,
        config: PickConfig | None,
        on_event: Callable[[ProgressEvent], None] | None,
        parser: CommandParser | None,
        validator: CommandValidator | None,
        recorder: Recorder | None = None,
    ) -> None:
        chosen = validator or getattr(cell.arm, "validator", None)
        if not isinstance(chosen, CommandValidator):
            chosen = CommandValidator(ValidatorConfig.for_robot(cell.robot), fk_tcp=cell.robot.fk_tcp)
        if recorder is not None and recorder.enabled:
            # The loop commands the devices through recording wrappers (`pipeline.recording`); the cell's
            # own devices stay as they are for the caller.
            gripper = ObservedGripper(cell.gripper, recorder)
            arm = ObservedArm(cell.arm, cell.robot, recorder, gripper=cell.gripper)
            cell = dataclasses.replace(cell, arm=arm, gripper=gripper)
        self.loop = Loop(cell, estimator, config or PickConfig(), chosen, on_event, recorder)
        self.parser = parser

    # The cell and settings, as the loop sees them.
    @property
    def cell(self) -> Cell:
        return self.loop.cell

    @property
    def config(self) -> PickConfig:
        return self.loop.config

    @property
    def validator(self) -> CommandValidator:
        return self.loop.validator

    @property
    def estimator(self) -> Estimator:
        return self.loop.estimator

    @property
    def gripper_kind(self) -> str:
        return self.loop.gripper_geometry.kind

    @property
    def arm(self) -> Arm:
        return self.loop.arm

    @property
    def gripper(self) -> Gripper:
        return self.loop.gripper

    @property
    def camera(self) -> RGBDCamera:
        return self.loop.camera

    @property
    def wrist_camera(self) -> RGBDCamera | None:
        return self.loop.wrist_camera

    @property
    def robot(self) -> RobotModel:
        return self.loop.robot

    @property
    def gripper_geometry(self) -> GripperGeometry:
        return self.loop.gripper_geometry

    @property
    def place_targets(self) -> Mapping[str, PlaceTarget]:
        return self.loop.place_targets

    # ------------------------------------------------------------------------------------------------ run
    def run(self, command: str | Command) -> PickOutcome:
        """Run one command to its end. Returns a `PickOutcome`; expected failures are reasons, not raises."""
        run = RunRecord()
        cmd: Command | None = None
        self.loop.recorder.begin_episode(command.text if isinstance(command, Command) else str(command))
        try:
            cmd = self._parse(command)
            fixture = self._fixture(cmd)
            q_home = self.loop.joints()
            n_objects = self.config.max_objects if cmd.plural else 1
            for k in range(n_objects):
                try:
                    self._one_object(run, cmd, fixture, q_home)
                except Abort as exc:
                    # A plural command ends well when nothing more is found after at least one object.
                    if k > 0 and exc.reason == "not_found":
                        break
                    raise
                run.objects_done += 1
                if k + 1 < n_objects:
                    go_home(self.loop, q_home)
            return self._finish(run, cmd, "success", _success_message(cmd, run))
        except Abort as exc:
            run.estimates.extend(exc.estimates)
            run.T_base_cams.extend([exc.T_base_cam] * len(exc.estimates))  # type: ignore[list-item]
            return self._finish(run, cmd, exc.reason, exc.message)
        except DEVICE_FAULTS as exc:
            reason = fault_reason(exc)
            logger.error("device fault: %s: %s", type(exc).__name__, exc)
            return self._finish(run, cmd, reason, stop_after_fault(self.loop, run, reason, exc))

    def _finish(self, run: RunRecord, cmd: Command | None, reason: Reason, message: str) -> PickOutcome:
        run.timings_s["total"] = time.perf_counter() - run.t_start
        self.loop.emit("done", f"{reason}: {message}", 1.0, len(run.attempts))
        logger.info("pick run ended: %s (%s)", reason, message)
        outcome = PickOutcome(
            reason=reason,
            message=message,
            command=cmd,
            estimates=tuple(run.estimates),
            T_base_cams=tuple(run.T_base_cams),
            attempts=tuple(run.attempts),
            grasp=run.grasp,
            place=run.place,
            timings_s=dict(run.timings_s),
            objects_done=int(run.objects_done),
        )
        self.loop.recorder.outcome(outcome)
        self.loop.recorder.end_episode()
        return outcome

    # --------------------------------------------------------------------------------------------- stages
    def _parse(self, command: str | Command) -> Command:
        """parse: the command text -> `Command`; "not_understood" with what was understood."""
        self.loop.emit("parse", f"parsing {command!r}", 0.0)
        if isinstance(command, Command):
            return command
        if self.parser is None:
            self.parser = CommandParser()
        try:
            return self.parser.parse(command)
        except (CommandNotUnderstood, InvalidInputError) as exc:
            raise Abort("not_understood", str(exc)) from None

    def _fixture(self, cmd: Command) -> PlaceTarget | None:
        """The cell's place fixture the command names (None: a pick, or a place target to ground)."""
        if cmd.action not in ("place", "stack") or cmd.target == "object":
            return None
        fixture = self.loop.place_targets.get(cmd.target or "")
        if fixture is None:
            known = ", ".join(sorted(self.loop.place_targets)) or "none configured"
            raise Abort("not_found", f"no place target {cmd.target!r} (known: {known})")
        return fixture

    def _one_object(
        self, run: RunRecord, cmd: Command, fixture: PlaceTarget | None, q_home: np.ndarray
    ) -> None:
        """Observe-ground-plan-execute-verify rounds for one object until it is held (and placed)."""
        loop, cfg = self.loop, self.config
        last = Abort("not_found", "no attempt was made")
        tried_at = None  # where the object tried in the last failed round stood (base) [m]
        avoid: list[np.ndarray] = []  # where a wrong object put back stands (base) [m]: not tried again
        rounds, round_ = cfg.max_estimates, 0
        while round_ < rounds:
            run.check_time(cfg.timeout_s)
            observations, frame = observe_candidates(loop, run, cmd, fixture, round_, tried_at, avoid)
            place_target = fixture
            if cmd.action in ("place", "stack") and fixture is None:
                place_target = ground_place_target(loop, run, cmd, frame, observations[0])
            try:
                self._attempt(run, cmd, observations, place_target)
                return
            except Abort as exc:
                if exc.reason in ("timeout", "camera_failed"):
                    raise
                last = exc
                logger.info("round %d failed: %s (%s)", round_ + 1, exc.reason, exc.message)
                if exc.reason == "wrong_object":
                    if exc.retry_at is None:  # not put back: still held, the arm stays where it is
                        raise
                    if not cfg.retry_wrong_object or avoid:
                        go_home(loop, q_home)
                        raise
                    # Once, in a round of its own: the better candidate first, the one put back never again.
                    rounds += 1
                    avoid.append(np.asarray(exc.held_at))
                    tried_at = np.asarray(exc.retry_at)
                elif cfg.candidate_order == "score":  # a stack of like things: any of them will do
                    tried_at = observations[0].target.pose.t
                go_home(loop, q_home)
            round_ += 1
        raise last

    def _attempt(
        self, run: RunRecord, cmd: Command, observations: list[Observation], place_target: PlaceTarget | None
    ) -> None:
        """plan (and look closer with the wrist camera), then execute and verify the grasps."""
        loop = self.loop
        obs, grasps, scene = choose_and_plan(loop, run, observations, place_target)
        if loop.wrist_camera is not None:
            refined = wrist_look(loop, run, obs, grasps.grasps[0], scene, cmd)
            if refined is not None:
                try:
                    grasps, scene = plan(loop, run, refined, loop.joints())
                    obs = refined
                except Abort as exc:  # the fixed camera's plan stands
                    logger.info("no grasp on the wrist estimate (%s); keeping the first plan", exc.message)
        try_grasps(loop, run, cmd, obs, grasps, scene, place_target)


def _success_message(cmd: Command, run: RunRecord) -> str:
    n = len(run.attempts)
    what = cmd.object_prompt if not cmd.plural else f"{run.objects_done} x {cmd.object_prompt}"
    where = cmd.target if cmd.target != "object" else cmd.target_prompt
    verb = "picked" if cmd.action == "pick" else f"placed ... on/in the {where}:"
    return f"{verb} {what!r} after {n} attempt(s)"
