"""The closed loop: command -> observe -> estimate -> plan grasps -> execute -> verify -> retry.

```
pnp = PickAndPlace(arm, gripper, camera, ProMPose.default(), robot, "parallel_jaw",
                   place_targets={"bin": PlaceTarget("bin", T_base_bin, [0.13, 0.10], 0.10)})
outcome = pnp.run("put the red mug in the bin")      # PickOutcome; outcome.reason, outcome.timings_s
```

Nothing here reads ground truth: the target is whatever the estimator grounds from the camera frames, the
grasp is planned on that estimate and the observed points, and success is judged from the gripper (jaws
stopped on something / suction contact) and a re-observation (the object is no longer where it stood).
Every captured frame first loses the depth readings that lie on the robot itself (its capsules at the
joints of the capture, `PickConfig.self_filter_margin_m`), so a link in view is never offered as an object.

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

A device fault ends the run at once, after the stop path (`_stop_after_fault`): after an e-stop or a lost
link nothing more is sent to the arm (an e-stopped controller takes no motion, a person may be at the cell,
and a dropped link may not carry a command); after the other faults the arm is told to stop. The gripper is
opened only where that cannot drop anything: closed on an object that still rests on its support (before the
lift) it is opened (not after an e-stop); closed on an object that may be in the air it stays closed, and the
outcome's message says so, as it says every state it leaves the gripper in.

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
camera must no longer see the object where it stood, nor see it hang from the jaws with a part still on the
support (it rose less than half the lift and some of its seen points lie on the support: a pan held by the
far side of its rim, its handle on the table). A grasp whose approach or lift line would flip a wrist
on the way (IK every 5 mm, seeded with the last) is skipped before anything moves.

Verification fails closed. Every frame must have the image size and intrinsics of its camera's first frame of
the run (a camera that changes mode mid-run), and a re-observation frame must have depth readings on at least
half the pixels the pick's view had them on, in the object's projected box (`_depth_gone`: a dropout): a
frame that fails is captured again, `camera_retries` times in all; then a lifted object is set down where it
was picked (`_set_down`) and the run ends "camera_failed". A re-observation that finds no object is judged on
the raw depth where the object stood (`_vacated`): still reading its surface is "slipped", no longer reading
it (seen past it, or the hand in front) is a lift, too few readings there is no evidence ("camera_failed",
set down).

No wrong-object success: after the lift (pick and place alike) the prompt is estimated again; the candidate
nearest the tcp and risen from where the object stood is what is held. When another candidate, standing where
the camera saw an object before the pick, fits the prompt clearly better (`PickConfig.wrong_object_margin` on
the calibrated `probability`) and about as well as the object chosen before the pick did (the held one, in
the air behind the jaws, reads low whatever it is), or the prompt names a colour the held object clearly
lacks while the other shows it, the object is put back (the lift line back down to its grasp pose,
validated first, then open and retreat) and the run ends
"wrong_object", or, with `retry_wrong_object`, the better candidate is tried once (the one put back never
again). Without probabilities, masks or a held candidate the check cannot judge and passes: it never
invents a wrong object.

A plural command ("move the cartons to the conveyor") repeats pick-and-place until no such object
is left (or `max_objects`). A place target that names no fixture of the cell ("in the white bowl", "on the tea
box") is grounded in the image like the object: the named object's estimated box becomes a bin (into) or a
surface (onto).

Every motion goes through the `Arm`'s own methods, which validate it (`CommandValidator`) before moving; a
refused command raises in the arm and leaves it still, and the loop counts it as a failed attempt.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import (
    AmbiguousObjectError,
    CameraError,
    InvalidInputError,
    NoFeasibleGrasp,
    NoFeasibleMotion,
    NoFeasiblePlace,
    ObjectNotFoundError,
    UnreachableError,
    UnsafeCommandError,
)
from prompose_grasp.geometry.pointcloud import back_project, valid_depth_mask
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import invert_T, transform_points
from prompose_grasp.grasp import (
    GraspConfig,
    ObjectModel,
    PlaceConfig,
    PlaceTarget,
    Plane,
    check_path,
    get_gripper,
    plan_grasps,
    plan_pick_place,
    plan_place,
)
from prompose_grasp.grasp.motion import MotionConfig, free_move, place_support_fixture, timed_trajectory
from prompose_grasp.grasp.place import footprint
from prompose_grasp.grasp.planner import build_scene, robot_pixel_mask, robot_self_capsules
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.perception.grounding.confidence import ConfidenceModel
from prompose_grasp.perception.grounding.score import total_of_score
from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser
from prompose_grasp.pipeline.describe import (
    colour_share,
    describe_contenders,
    object_noun,
    phrase,
    positions,
    prompt_colour,
)
from prompose_grasp.pipeline.outcome import AttemptRecord, PickOutcome, ProgressEvent
from prompose_grasp.robot.interfaces import (
    ConnectionLostError,
    EmergencyStopError,
    GripperError,
    MotionFailedError,
    RGBDFrame,
    SafetyStopError,
)
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

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
        grip_force_n: jaw force per finger [N] (suction holds with the cup's full `max_force_n`).
        min_jaw_width_m: jaws closed narrower than this held nothing [m] (the 2F-85 class stops at 0); for a
            grasp planned on a thinner part (a cup's wall) half its planned width, at least 1 mm.
        moved_min_m: on re-observation the object counts as picked when its estimate's centre moved or its
            top rose more than this (or it is no longer seen where it stood) [m]. A third of the 10 cm
            lift: a bowl held by its rim hangs tilted and its estimate rose only 49-50 mm (seed 102,
            dropped as "still where it stood" at 5 cm), while an unmoved object's re-estimate moves ~1-2 cm
            (noise, the gripper above it).
        max_scene_points: observed points handed to the collision scene (evenly thinned) [-].
        reobserve: re-observe after the lift to confirm the pick.
        open_margin_m: the jaws open this much wider than the object plus the planner's clearance before the
            approach (not the full stroke: a narrower hand fits between neighbours) [m]. It is planned in:
            the grasp's opening, and so the approach's collision check, include it.
        candidates: estimator candidates considered per observation (estimators with `estimate_all`).
        candidate_ratio: candidates scoring at least this fraction of the best one count as the object [-].
        candidate_order: the order those candidates are tried in: "top_first" (highest top first: the top
            layer of a stack of like objects, a pallet of cartons) or "score" (the best match first: a
            tabletop of different things, where a candidate at 90 % of the best score is often another
            object, e.g. a tea box's 0.76 next to its 0.84 on a bottle and a can behind it).
        candidate_max_size_ratio: or None; else candidates whose box differs from the best match's by more
            than this factor in any (sorted) extent are tried after the alike ones: another kind of thing
            (a 0.5 m "tea box" over a bottle and a can, next to the 12 cm tea box that scored best).
        max_objects: objects moved by one plural command at most.
        lift_clearance_m: the lift after a grasp rises at least the object's estimated height plus this, so
            the held object clears what stood beside it (cartons in a layer) [m].
        max_lift_m: ... but at most this [m].
        max_object_height_m: the tallest object the cell handles [m], or None. A box estimated taller (an
            amodal box reaching down to the floor through a stack: from above, the height of a carton on
            other cartons is not seen) is carried and put down as this tall, its top kept: the transfer
            clears the neighbours and the place releases just above the surface.
        wrist_look_m: with a wrist camera, the arm first looks at the target from the best grasp's pre-grasp
            raised this much more; the closer estimate replaces the fixed camera's and the grasps are planned
            again on it (tracking the target on approach) [m].
        wrist_max_shift_m: a wrist estimate farther than this from the fixed camera's is another object and
            is ignored [m].
        pad_depth_margin_m: jaw grasps with the pads' centre this much deeper than half a pad inside the
            estimated box are tried first (robust to the estimate's ~1 cm error) [m].
        self_filter_margin_m: depth readings within this of the arm's and gripper's capsules at the joints of
            the capture are the robot itself and are dropped before estimating (robot self-filtering: a link
            in view is otherwise grounded as an object), or None to keep them [m].
        wrong_object_margin: after the lift, a still standing candidate whose calibrated `probability`
            exceeds the held object's by more than this means the wrong object was picked [-]. The held
            object is seen lifted and partly hidden by the gripper, which lowers its own match (its height
            above the table, size class and shape are measured on that view), so a small lead of a standing
            object is no evidence; the probabilities sum to at most 1, so a lead of 0.3 leaves the held one
            at most 0.35 and the other at least ~1.9 times as likely. Judged only for a command naming one
            object with `candidate_order="score"`: a plural command or a stack takes any object that fits.
        retry_wrong_object: after putting a wrong object back, try the candidate that fits better, once;
            False ends the run "wrong_object".
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
    moved_min_m: float = 0.035
    max_scene_points: int = 40000
    reobserve: bool = True
    open_margin_m: float = 0.01
    candidates: int = 4
    candidate_ratio: float = 0.9
    candidate_order: str = "top_first"
    candidate_max_size_ratio: float | None = None
    max_objects: int = 12
    lift_clearance_m: float = 0.03
    max_lift_m: float = 0.35
    pad_depth_margin_m: float = 0.01
    max_object_height_m: float | None = None
    wrist_look_m: float = 0.15
    wrist_max_shift_m: float = 0.10
    self_filter_margin_m: float | None = 0.03
    wrong_object_margin: float = 0.3
    retry_wrong_object: bool = True
    grasp: GraspConfig | None = None

    def __post_init__(self) -> None:
        ints = (
            "max_estimates",
            "grasps_per_estimate",
            "camera_retries",
            "observe_frames",
            "max_scene_points",
            "candidates",
            "max_objects",
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
            "open_margin_m",
            "candidate_ratio",
            "lift_clearance_m",
            "max_lift_m",
            "pad_depth_margin_m",
            "wrist_look_m",
            "wrist_max_shift_m",
        )
        for name in floats:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"PickConfig.{name} must be finite and > 0, got {v}")
        if not 0.0 < float(self.wrong_object_margin) < 1.0:  # a difference of probabilities
            raise InvalidInputError(
                f"PickConfig.wrong_object_margin must be in (0, 1), got {self.wrong_object_margin}"
            )
        r = self.candidate_max_size_ratio
        if r is not None and not (math.isfinite(float(r)) and float(r) >= 1.0):
            raise InvalidInputError(f"PickConfig.candidate_max_size_ratio must be None or >= 1, got {r}")
        if self.candidate_order not in _CANDIDATE_ORDERS:
            raise InvalidInputError(
                f"PickConfig.candidate_order must be one of {', '.join(_CANDIDATE_ORDERS)}, "
                f"got {self.candidate_order!r}"
            )
        m = self.self_filter_margin_m
        if m is not None and not (math.isfinite(float(m)) and float(m) >= 0):
            raise InvalidInputError(f"PickConfig.self_filter_margin_m must be None or >= 0 m, got {m}")
        h = self.max_object_height_m
        if h is not None and not (math.isfinite(float(h)) and float(h) > 0):
            raise InvalidInputError(f"PickConfig.max_object_height_m must be None or > 0 m, got {h}")


#: `PickConfig.candidate_order` choices.
_CANDIDATE_ORDERS = ("top_first", "score")

#: Device faults and the outcome each ends a run in, the first class that matches (an e-stop is a safety stop
#: too; any other stop the controller's safety functions make is protective).
_FAULTS: tuple[tuple[type[Exception], str], ...] = (
    (EmergencyStopError, "emergency_stop"),
    (SafetyStopError, "protective_stop"),
    (ConnectionLostError, "connection_lost"),
    (MotionFailedError, "motion_failed"),
    (GripperError, "gripper_failed"),
)
_DEVICE_FAULTS: tuple[type[Exception], ...] = tuple(c for c, _ in _FAULTS)


def _fault_reason(exc: BaseException) -> str:
    """The outcome reason of a device fault (`_FAULTS`)."""
    return next(reason for cls, reason in _FAULTS if isinstance(exc, cls))


@dataclass
class _Grip:
    """What the loop last told the gripper, for the stop path after a device fault: `closed` from the first
    close command on (a fault mid-close leaves the jaws closing) until it opens; `lifted` once an arm motion
    started while closed (the object may be off its support, and opening would drop it)."""

    closed: bool = False
    lifted: bool = False


class _Abort(Exception):
    """Ends a run with a typed reason (internal; never escapes `run`). `estimates` (camera frame of
    `T_base_cam`) go into the outcome ("ambiguous": the contenders); "wrong_object" says where the object put
    back stands (`held_at`) and where the one that fits better does (`retry_at`), in base [m]. `judged`: a
    "not_found" the grounder decided on the candidates it saw (nothing fits the words), not an empty frame."""

    def __init__(
        self,
        reason: str,
        message: str,
        estimates: Sequence[Any] = (),
        T_base_cam: np.ndarray | None = None,
        held_at: np.ndarray | None = None,
        retry_at: np.ndarray | None = None,
        judged: bool = False,
    ):
        super().__init__(message)
        self.judged = judged
        self.reason = reason
        self.message = message
        self.estimates = tuple(estimates)
        self.T_base_cam = T_base_cam
        self.held_at = held_at
        self.retry_at = retry_at


@dataclass(frozen=True, eq=False)
class _Observation:
    """One observation of the target: the frame, the estimate chosen, the target in `base`, the support
    plane, the observed points in `base` [m], and the other candidates (tried when this one has no grasp)."""

    frame: RGBDFrame
    estimate: Any
    target: ObjectModel
    support: Plane | None
    points_base: np.ndarray
    q_seen: np.ndarray


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
        validator: CommandValidator | None = None,
        wrist_camera: Any | None = None,
    ):
        self.arm = arm
        self.wrist_camera = wrist_camera
        self._T_flange_wrist_cam: np.ndarray | None = None  # learned at the first wrist look
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
        chosen = validator or getattr(arm, "validator", None)
        if not isinstance(chosen, CommandValidator):
            chosen = CommandValidator(ValidatorConfig.for_robot(robot_model), fk_tcp=robot_model.fk_tcp)
        self.validator: CommandValidator = chosen
        self._grip = _Grip()  # what the gripper was last told (the stop path after a device fault)
        self._modes: dict[int, tuple[float, ...]] = {}  # each camera's image size and intrinsics this run
        self._last_raw_frame: RGBDFrame | None = None  # the last frame `_capture` took, robot included

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
            "done": 0,
            "placed": [],  # ObjectModels of what this run put down (obstacles for the next place)
        }
        cmd: Command | None = None
        self._grip = _Grip()
        self._modes = {}
        self._last_raw_frame = None

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
                objects_done=int(state["done"]),
            )

        try:
            cmd = self._parse(command)
            fixture = None
            if cmd.action in ("place", "stack") and cmd.target != "object":
                fixture = self.place_targets.get(cmd.target or "")
                if fixture is None:
                    known = ", ".join(sorted(self.place_targets)) or "none configured"
                    raise _Abort("not_found", f"no place target {cmd.target!r} (known: {known})")
            q_home = np.asarray(self.arm.joint_positions(), dtype=np.float64)
            n_objects = self.config.max_objects if cmd.plural else 1
            for k in range(n_objects):
                try:
                    self._one_object(cmd, fixture, q_home, timings, state, t_start)
                except _Abort as exc:
                    # A plural command ends well when nothing more is found after at least one object.
                    if k > 0 and exc.reason == "not_found":
                        break
                    raise
                state["done"] += 1
                if k + 1 < n_objects:
                    self._go_home(q_home)
            return finish("success", self._success_message(cmd, state))
        except _Abort as exc:
            state["estimates"].extend(exc.estimates)
            state["T_base_cams"].extend([exc.T_base_cam] * len(exc.estimates))
            return finish(exc.reason, exc.message)
        except _DEVICE_FAULTS as exc:
            reason = _fault_reason(exc)
            logger.error("device fault: %s: %s", type(exc).__name__, exc)
            return finish(reason, self._stop_after_fault(reason, exc))

    def _stop_after_fault(self, reason: str, exc: BaseException) -> str:
        """The stop path after a device fault (see the module's docstring); returns the outcome's message: the
        fault, what was sent after it, and the state the gripper is left in."""
        notes = [str(exc)]
        if reason in ("emergency_stop", "connection_lost"):
            notes.append("nothing more was sent to the arm")
        else:
            try:
                self.arm.stop()
                notes.append("the arm was told to stop")
            except Exception as stop_exc:  # the stop path goes on, and reports whatever the device raised
                notes.append(f"the arm's stop command failed ({type(stop_exc).__name__}: {stop_exc})")
        grip = self._grip
        if not grip.closed:
            notes.append("the gripper is open")
        elif grip.lifted:
            notes.append(
                "the gripper is still closed on the object, which may be off its support (opening would "
                "drop it): take hold of the object, then open the gripper"
            )
        elif reason == "emergency_stop":
            notes.append("the gripper is still closed (nothing is sent after an e-stop): open it when safe")
        else:
            try:
                self._open_jaws()
                notes.append("the gripper was opened (the object rests on its support)")
            except Exception as open_exc:  # as above
                notes.append(
                    f"the gripper is still closed: opening it failed ({type(open_exc).__name__}: {open_exc})"
                )
        return "; ".join(notes)

    def _close_jaws(self) -> None:
        """Close the gripper with the grip force (vacuum on), noting it for the stop path."""
        self._grip = _Grip(closed=True)
        self.gripper.close(self._grip_force())

    def _open_jaws(self) -> None:
        """Open the gripper fully (vacuum off), noting it for the stop path."""
        self.gripper.open()
        self._grip = _Grip()

    def _moving_closed(self) -> None:
        """An arm motion starts: with the gripper closed, the object may leave its support from now on."""
        self._grip.lifted = self._grip.closed

    def _one_object(
        self,
        cmd: Command,
        fixture: PlaceTarget | None,
        q_home: np.ndarray,
        timings: dict[str, float],
        state: dict[str, Any],
        t_start: float,
    ) -> None:
        """Observe-estimate-plan-execute rounds for one object until it is held (and placed)."""
        last = _Abort("not_found", "no attempt was made")
        tried_at = None  # where the object tried in the last failed round stood (base) [m]
        avoid: list[np.ndarray] = []  # where a wrong object put back stands (base) [m]: not tried again
        rounds, round_ = self.config.max_estimates, 0
        while round_ < rounds:
            self._check_time(t_start)
            observations, frame = self._observe_candidates(
                cmd, fixture, timings, state, round_, tried_at, avoid
            )
            place_target = fixture
            if cmd.action in ("place", "stack") and fixture is None:
                place_target = self._ground_place_target(cmd, frame, observations[0], timings, state)
            try:
                self._attempt_round(observations, cmd, place_target, timings, state, t_start)
                return
            except _Abort as exc:
                if exc.reason in ("timeout", "camera_failed"):
                    raise
                last = exc
                logger.info("round %d failed: %s (%s)", round_ + 1, exc.reason, exc.message)
                if exc.reason == "wrong_object":
                    if exc.retry_at is None:  # not put back: still held, the arm stays where it is
                        raise
                    if not self.config.retry_wrong_object or avoid:
                        self._go_home(q_home)
                        raise
                    # Once, in a round of its own: the better candidate first, the one put back never again.
                    rounds += 1
                    avoid.append(np.asarray(exc.held_at))
                    tried_at = np.asarray(exc.retry_at)
                elif self.config.candidate_order == "score":  # a stack of like things: any of them will do
                    tried_at = observations[0].target.pose.t
                self._go_home(q_home)
            round_ += 1
        raise last

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
        except (CommandNotUnderstood, InvalidInputError) as exc:
            raise _Abort("not_understood", str(exc)) from None

    def _capture(self, check: Callable[[RGBDFrame], str | None] | None = None) -> RGBDFrame:
        """The next frame the loop can trust, without the robot's own depth readings. A dropped frame, one
        whose image size or intrinsics differ from this camera's first frame of the run (a camera that
        changed mode mid-run: the hand-eye calibration and the depth registration hold for one), and one
        that `check` (the raw frame -> why it cannot be trusted, or None) refuses are retried
        `camera_retries` times in all, then "camera_failed"."""
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
            K = frame.intrinsics
            mode = (float(K.width), float(K.height), K.fx, K.fy, K.cx, K.cy)
            first = self._modes.setdefault(id(self.camera), mode)
            why = None
            if mode != first:
                why = (
                    f"the camera's image size and intrinsics changed mid-run (w, h, fx, fy, cx, cy "
                    f"{_mode_text(first)} -> {_mode_text(mode)})"
                )
            elif check is not None:
                why = check(frame)
            if why is not None:
                errors.append(why)
                logger.warning("frame not trusted (%s); capturing again", why)
                continue
            self._last_raw_frame = frame
            return self._without_robot(frame)
        raise _Abort(
            "camera_failed",
            f"{self.config.camera_retries} captures failed; last: {errors[-1] if errors else '?'}",
        )

    def _without_robot(self, frame: RGBDFrame) -> RGBDFrame:
        """The frame with no depth reading where it sees the robot itself (`PickConfig.self_filter_margin_m`):
        the arm stands still while the loop observes, so its joints now are its joints at the capture."""
        margin = self.config.self_filter_margin_m
        if margin is None:
            return frame
        capsules = robot_self_capsules(self.robot, self.gripper_geometry, self.arm.joint_positions())
        on_robot = robot_pixel_mask(frame.depth_m, frame.intrinsics, frame.T_base_cam, capsules, margin)
        if not on_robot.any():
            return frame
        logger.debug("self-filter: %d depth pixels on the robot dropped", int(on_robot.sum()))
        return dataclasses.replace(frame, depth_m=np.where(on_robot, np.float32(0.0), frame.depth_m))

    def _estimates(
        self,
        prompt: str,
        timings: dict[str, float],
        min_score_ratio: float | None = None,
        judge: bool = False,
        check: Callable[[RGBDFrame], str | None] | None = None,
    ) -> tuple[RGBDFrame, list[Any]]:
        """Capture `observe_frames` frames and estimate the prompt: the candidates, best first (one with a
        tracker over several frames or an estimator without `estimate_all`). Nothing found is retried on
        fresh frames `camera_retries` times (a transient depth hole or occlusion) before "not_found"; an
        "ambiguous" answer (`judge`) is not retried, and neither is a "not_found" the grounder judged on the
        candidates it saw: asking fresh frames until sensor noise makes one of them clear would turn a
        refusal into a guess (the chance of a spurious clear winner grows with every frame asked)."""
        for k in range(self.config.camera_retries):
            try:
                return self._estimates_once(prompt, timings, min_score_ratio, judge, check)
            except _Abort as exc:
                if exc.reason != "not_found" or exc.judged or k + 1 == self.config.camera_retries:
                    raise
                logger.info("nothing found (%s); observing again", exc.message)
        raise _Abort("not_found", "no observation")  # not reached: the loop returns or raises

    def _estimates_once(
        self,
        prompt: str,
        timings: dict[str, float],
        min_score_ratio: float | None = None,
        judge: bool = False,
        check: Callable[[RGBDFrame], str | None] | None = None,
    ) -> tuple[RGBDFrame, list[Any]]:
        """Capture and estimate; the candidates' estimates, best first (those scoring under `min_score_ratio`
        of the best are not fitted; `candidate_ratio` when None).

        The best estimate's `contenders` (or `AmbiguousObjectError`, whose estimates are then the answer):
        0 is "not_found"; 2 or more is "ambiguous" when `judge` (the command names one object and any of
        them will not do), else the contenders are candidates like any; -1 (not judged) changes nothing."""
        ratio = self.config.candidate_ratio if min_score_ratio is None else min_score_ratio
        refused: AmbiguousObjectError | None = None
        t0 = time.perf_counter()
        frames = [self._capture(check) for _ in range(self.config.observe_frames)]
        timings["observe"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            if len(frames) > 1:
                ests = [list(self.estimator.track(frames, prompt))[-1]]
            elif hasattr(self.estimator, "estimate_all") and self.config.candidates > 1:
                n = self.config.candidates
                ests = list(
                    self.estimator.estimate_all(frames[0], prompt, max_objects=n, min_score_ratio=ratio)
                )
                if not ests:
                    raise ObjectNotFoundError(f"no object in the frame matches {prompt!r}")
            else:
                ests = [self.estimator.estimate(frames[0], prompt)]
        except AmbiguousObjectError as exc:  # `estimate` / `track` would not choose among its estimates
            refused, ests = exc, list(exc.estimates)
        except ObjectNotFoundError as exc:
            raise _Abort("not_found", str(exc)) from None
        except InvalidInputError as exc:  # e.g. a depth image without a single reading
            raise _Abort("not_found", f"the frame cannot be used: {exc}") from None
        finally:
            timings["estimate"] += time.perf_counter() - t0
        frame = frames[-1]
        contenders = int(getattr(ests[0], "contenders", -1)) if ests else -1
        if refused is not None:
            contenders = max(contenders, len(ests), 2)
        if contenders == 0:
            raise _Abort("not_found", f"nothing in the frame fits the words of {prompt!r}", judged=True)
        if judge and contenders >= 2:
            T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
            fit = ests[:contenders]
            message = describe_contenders(prompt, fit, T_base_cam, contenders) if fit else str(refused)
            raise _Abort("ambiguous", message, fit, T_base_cam)
        if not ests:  # refused without an estimate to show
            raise _Abort("not_found", str(refused))
        return frame, ests

    def _estimate(self, prompt: str, timings: dict[str, float]) -> tuple[RGBDFrame, Any]:
        frame, ests = self._estimates(prompt, timings)
        return frame, ests[0]

    def _to_base(self, est: Any, T_base_cam: np.ndarray, name: str) -> tuple[ObjectModel, Plane | None]:
        pose_base = est.pose.transformed(T_base_cam)
        mesh = None
        if getattr(est, "mesh_cam", None) is not None:
            mesh = est.mesh_cam.copy()
            mesh.apply_transform(T_base_cam)
        surface = getattr(est, "surface_cam", None)
        if surface is not None:
            surface = transform_points(T_base_cam, surface)
        target = ObjectModel(
            name, pose_base, mesh=mesh, family=est.prior.name, symmetry=est.prior.symmetry,
            surface_points=surface,
        )  # fmt: skip
        support = None
        if est.support_plane is not None:
            support = Plane.from_camera(est.support_plane.normal_cam, est.support_plane.offset_m, T_base_cam)
        return target, support

    def _observe_candidates(
        self,
        cmd: Command,
        fixture: PlaceTarget | None,
        timings: dict[str, float],
        state: dict[str, Any],
        round_: int,
        tried_at: np.ndarray | None = None,
        avoid: Sequence[np.ndarray] = (),
    ) -> tuple[list[_Observation], RGBDFrame]:
        """Observe and estimate; the candidates that count as the object, in the order they are tried.

        `tried_at`: where the object of a failed round stood (base) [m], with `candidate_order` "score" (a
        tabletop of different things; in a stack of like things another one will do: depalletising seed 32's
        top carton could not be carried past the forearm, the next round took its neighbour). Objects do not
        move by themselves: a candidate still there (within `_SAME_PLACE_M`) is tried first, whatever its
        score this time (a noisy frame can rank a neighbour higher, or put the target's score under
        `candidate_ratio`).

        `avoid`: where a wrong object was put back (base) [m]; a candidate there (within `_SAME_PLACE_M`) is
        not tried. The first observation of an object judges ambiguity (`_estimates_once`) unless the
        command takes any object that fits: a plural one, or `candidate_order` "top_first" (like things)."""
        frac = min(round_ / self.config.max_estimates, 1.0)
        q_seen = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        self._emit("observe", f"observing ({self.config.observe_frames} frame(s))", 0.05 + 0.9 * frac)
        ratio = self.config.candidate_ratio if tried_at is None else 0.0
        judge = tried_at is None and not self._any_will_do(cmd)
        frame, ests = self._estimates(cmd.object_prompt, timings, ratio, judge)
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        points = transform_points(T_base_cam, back_project(frame.depth_m, frame.intrinsics))
        stride = max(1, len(points) // self.config.max_scene_points)
        points = points[::stride]
        best = max(float(getattr(e, "score", 1.0)) for e in ests)
        observations, still_there = [], []
        for est in ests:
            target, support = self._to_base(est, T_base_cam, "target")
            if any(np.linalg.norm(target.pose.t - p) <= _SAME_PLACE_M for p in avoid):
                continue  # the wrong object, put back
            if tried_at is not None and np.linalg.norm(target.pose.t - tried_at) <= _SAME_PLACE_M:
                still_there.append(_Observation(frame, est, target, support, points, q_seen))
                continue
            if float(getattr(est, "score", 1.0)) < self.config.candidate_ratio * best:
                continue
            if fixture is not None and _at_target(target, fixture):
                continue  # already where the command wants it
            observations.append(_Observation(frame, est, target, support, points, q_seen))
        if not observations and not still_there:
            if avoid:
                raise _Abort("not_found", f"no {cmd.object_prompt!r} in view but the wrong object put back")
            raise _Abort("not_found", f"every {cmd.object_prompt!r} in view is already on the {cmd.target}")
        if self.config.candidate_order == "top_first":
            # What lies on top first (the top layer of a stack): highest top along the support normal.
            observations.sort(key=lambda o: -_top_height(o.target, o.support))
        else:  # "score": the best match first (candidates come best first)
            observations.sort(key=lambda o: -_score(o))
        ratio = self.config.candidate_max_size_ratio
        if ratio is not None and observations:
            # Candidates unlike the best match in size (a box 6x taller than the tea box it scored next to)
            # are another thing: tried after the alike ones, each group in the order above.
            ref = np.sort(max(observations, key=_score).target.pose.size)
            alike = [_size_ratio(o.target.pose.size, ref) <= ratio for o in observations]
            observations = [o for o, a in zip(observations, alike) if a] + [
                o for o, a in zip(observations, alike) if not a
            ]
        if still_there:
            assert tried_at is not None
            still_there.sort(key=lambda o: float(np.linalg.norm(o.target.pose.t - tried_at)))
            observations = still_there + observations
        logger.info(
            "candidates for %r: %s",
            cmd.object_prompt,
            "; ".join(f"{_score(o):.3f} at {np.round(o.target.pose.t, 3).tolist()}" for o in observations),
        )
        chosen = observations[0]
        state["estimates"].append(chosen.estimate)
        state["T_base_cams"].append(T_base_cam)
        pose_base = chosen.target.pose
        self._emit(
            "estimate",
            f"{cmd.object_prompt!r}: {chosen.estimate.prior.name} at {np.round(pose_base.t, 3).tolist()} m, "
            f"size {np.round(pose_base.size, 3).tolist()} m ({len(observations)} candidate(s))",
            0.15 + 0.9 * frac,
        )
        return observations, frame

    def _ground_place_target(
        self,
        cmd: Command,
        frame: RGBDFrame,
        obs: _Observation,
        timings: dict[str, float],
        state: dict[str, Any],
    ) -> PlaceTarget:
        """The object the target phrase names, grounded in `frame`, as a place target: a bin when the command
        says "in" or the object is a container (bowl, cup, mug, bin, basket), else the surface of its top."""
        t0 = time.perf_counter()
        prompt = cmd.target_prompt
        try:
            est = self.estimator.estimate(frame, prompt)
        except AmbiguousObjectError as exc:
            T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
            fit = exc.estimates
            text = describe_contenders(prompt, fit, T_base_cam) if fit else str(exc)
            raise _Abort("ambiguous", f"place target: {text}", fit, T_base_cam) from None
        except ObjectNotFoundError as exc:
            raise _Abort("not_found", f"place target: {exc}") from None
        except InvalidInputError as exc:
            raise _Abort("not_found", f"place target {prompt!r}: {exc}") from None
        finally:
            timings["estimate"] += time.perf_counter() - t0
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        obj, support = self._to_base(est, T_base_cam, "place target")
        if np.linalg.norm(obj.pose.t - obs.target.pose.t) < 0.02:
            raise _Abort("not_found", f"the place {prompt!r} is the object to pick itself")
        up = np.array([0.0, 0.0, 1.0]) if support is None else np.asarray(support.normal)
        R = obj.pose.R
        # The object axis nearest the support normal is its height; the other two span its footprint.
        k_up = int(np.argmax(np.abs(R.T @ up)))
        others = [i for i in range(3) if i != k_up]
        x_axis = R[:, others[0]] - (R[:, others[0]] @ up) * up
        x_axis /= np.linalg.norm(x_axis)
        y_axis = np.cross(up, x_axis)
        half_xy = obj.pose.size[others] / 2.0
        height = float(obj.pose.size[k_up])
        container = cmd.into or est.prior.name in _CONTAINERS
        top = obj.pose.t + 0.5 * height * up
        if container:
            # The inner floor: a wall of ~8 % of the width each side, the floor ~10 % of the height up.
            floor = obj.pose.t - 0.5 * height * up + 0.1 * height * up
            T = np.eye(4)
            T[:3, :3] = np.column_stack([x_axis, y_axis, up])
            T[:3, 3] = floor
            target = PlaceTarget("bin", T, 0.84 * half_xy, 0.9 * height)
        else:
            T = np.eye(4)
            T[:3, :3] = np.column_stack([x_axis, y_axis, up])
            T[:3, 3] = top
            target = PlaceTarget("surface", T, half_xy, 0.0)
        state.setdefault("place_objects", []).append(obj)
        self._emit(
            "estimate",
            f"place target {prompt!r}: {est.prior.name} ({target.kind}) at {np.round(T[:3, 3], 3).tolist()}",
            0.25,
        )
        return target

    def _carried(self, obs: _Observation) -> ObjectModel:
        """The target as carried and put down: its box capped at `max_object_height_m` along the support
        normal, the top kept (the estimate's top face is what the camera saw)."""
        cap = self.config.max_object_height_m
        height = _height(obs.target, obs.support)
        if cap is None or height <= cap:
            return obs.target
        up = np.array([0.0, 0.0, 1.0]) if obs.support is None else np.asarray(obs.support.normal)
        pose = obs.target.pose
        k_up = int(np.argmax(np.abs(pose.R.T @ up)))
        size = np.array(pose.size, dtype=np.float64)
        size[k_up] = cap
        t = pose.t + 0.5 * (height - cap) * up
        return ObjectModel(obs.target.name, Pose9D(pose.R, t, size), family=obs.target.family)

    def _grasp_config(self, obs: _Observation) -> GraspConfig:
        """The planner's settings for this target: the lift clears the object's own height, and the opening
        includes `open_margin_m` (half on each side), so the approach is checked at the commanded width."""
        cfg = self.config.grasp or GraspConfig()
        height = _height(self._carried(obs), obs.support)
        lift = min(max(cfg.lift_m, height + self.config.lift_clearance_m), self.config.max_lift_m)
        clearance = cfg.clearance_m + 0.5 * self.config.open_margin_m
        return dataclasses.replace(cfg, lift_m=lift, clearance_m=clearance)

    def _plan(
        self, obs: _Observation, q_now: np.ndarray, timings: dict[str, float]
    ) -> tuple[Any, CollisionScene]:
        t0 = time.perf_counter()
        cfg = self._grasp_config(obs)
        try:
            grip = self.gripper_geometry
            P = obs.points_base
            scene = build_scene(obs.target, self.robot, grip, (), obs.support, P, obs.q_seen, cfg)
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
        observations: list[_Observation],
        cmd: Command,
        place_target: PlaceTarget | None,
        timings: dict[str, float],
        state: dict[str, Any],
        t_start: float,
    ) -> None:
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        self._emit("plan", "planning grasps", 0.3)
        plan, scene, obs, plan_failure = None, None, observations[0], None
        for candidate in observations:  # the first candidate with a feasible grasp
            if self._no_room(candidate, place_target):
                plan_failure = plan_failure or _Abort(
                    "no_feasible_grasp", "no feasible place pose (rejected: no_room: the estimate is larger)"
                )
                continue
            try:
                plan, scene = self._plan(candidate, q_now, timings)
            except _Abort as exc:
                plan_failure = plan_failure or exc
                continue
            obs = candidate
            break
        if plan is None or scene is None:
            raise plan_failure or _Abort("no_feasible_grasp", "no candidate to plan for")
        if obs is not observations[0]:  # the estimate actually used comes last in the outcome
            state["estimates"].append(obs.estimate)
            state["T_base_cams"].append(np.asarray(obs.frame.T_base_cam, dtype=np.float64))
        if self.wrist_camera is not None:
            refined = self._wrist_look(obs, plan.grasps[0], scene, cmd, timings, state)
            if refined is not None:
                try:
                    plan, scene = self._plan(refined, np.asarray(self.arm.joint_positions()), timings)
                    obs = refined
                except _Abort as exc:  # the fixed camera's plan stands
                    logger.info("no grasp on the wrist estimate (%s); keeping the first plan", exc.message)
        grasps = self._robust_first(plan.grasps, obs.target)
        held_scene = None
        if place_target is not None:
            held_scene = self._held_scene(obs, place_target, state, timings)
        failures: list[_Abort] = []
        tried = 0
        for i, planned in enumerate(grasps):
            if tried >= self.config.grasps_per_estimate:
                break
            self._check_time(t_start)
            grasp = self._deepened(self._pressed(planned), obs.target, scene)
            if not self._lines_continuous(grasp):
                # The arm's linear approach or lift would flip a wrist on the way (refused halfway): skip
                # the grasp before anything moves (it does not count as a try).
                logger.info("grasp %d skipped: its approach or lift line is not continuous in joint space", i)
                continue
            tried += 1
            n = len(state["attempts"]) + 1
            self._emit(
                "execute",
                f"grasp {i + 1}/{len(plan)} ({grasp.method}, quality {grasp.quality:.2f})",
                0.45,
                n,
            )
            try:
                if place_target is None or held_scene is None:
                    width = self._pick(grasp, scene, timings)
                    self._reobserve(cmd, obs, grasp, timings, state)
                else:
                    width = self._pick_place(
                        obs, grasp, place_target, scene, held_scene, timings, state, n, cmd
                    )
            except _DEVICE_FAULTS as exc:  # the run ends (`run`): the attempt says where the fault struck
                state["attempts"].append(AttemptRecord(n, grasp, _fault_reason(exc), str(exc)))
                raise
            except _Abort as exc:
                state["attempts"].append(AttemptRecord(n, grasp, exc.reason, exc.message))
                if exc.reason in ("timeout", "camera_failed", "wrong_object"):  # not another grasp of it
                    raise
                failures.append(exc)
                if exc.reason == "slipped":  # the object may have moved: re-estimate
                    break
                continue
            state["attempts"].append(AttemptRecord(n, grasp, "success", "held", width))
            state["grasp"] = grasp
            return
        if not failures:
            if tried == 0 and grasps:
                raise _Abort("ik_failed", f"all {len(grasps)} grasps' approach or lift lines flip a wrist")
            raise _Abort("no_feasible_grasp", "the plan held no grasp")
        raise failures[-1]

    def _no_room(self, obs: _Observation, target: PlaceTarget | None) -> bool:
        """The candidate's carried box is wider than a surface or bin place target in both orientations (the
        footprint `plan_place` lays out): no place can take it. A stack's estimate that merged two cartons
        (0.75 m across, against the 0.5 m belt) was grasped, then refused as "no room", once per grasp and
        round, while the single cartons beside it were never tried."""
        if target is None or target.kind == "pallet":
            return False
        carried = self._carried(obs)
        R = np.asarray(target.T_base_surface, dtype=np.float64)[:3, :3].T @ carried.pose.R
        half, _ = footprint(R, np.asarray(carried.pose.size, dtype=np.float64))
        room = np.asarray(target.half_extents_xy_m, dtype=np.float64)
        return bool(np.any(half > room) and np.any(half[::-1] > room))

    def _wrist_look(
        self,
        obs: _Observation,
        grasp: Any,
        scene: CollisionScene,
        cmd: Command,
        timings: dict[str, float],
        state: dict[str, Any],
    ) -> _Observation | None:
        """Move the wrist camera above the target (the best grasp's pre-grasp, `wrist_look_m` higher), observe
        and estimate there; when the target is not seen from there, look once more from that pose moved
        sideways so that the camera's optical axis runs through the target (the camera sits beside the tool:
        along the tool's axis a target at the reach's far end lies at the image's edge, half behind the
        fingers). The observation with the wrist's estimate, or None (no look pose, nothing seen, or an
        estimate too far from the first: another object)."""
        T_look = np.array(grasp.T_base_pregrasp)
        T_look[:3, 3] -= self.config.wrist_look_m * T_look[:3, 2]  # further back along the approach
        seen = self._look_from(T_look, grasp.q, obs, scene, cmd, timings, state)
        if seen is not None:
            return seen
        T_flange_cam = self._wrist_mount()
        if T_flange_cam is None:
            return None
        T_tcp_cam = invert_T(self.robot.T_flange_tcp) @ T_flange_cam
        centred = _aim_camera(T_look, T_tcp_cam, obs.target.pose.t)
        # Seeded with the joints now (at the first look, a few centimetres away): the nearest branch, not a
        # turn of the wrist that costs seconds of motion.
        return self._look_from(centred, None, obs, scene, cmd, timings, state)

    def _look_from(
        self,
        T_look: np.ndarray,
        q_seed: np.ndarray | None,
        obs: _Observation,
        scene: CollisionScene,
        cmd: Command,
        timings: dict[str, float],
        state: dict[str, Any],
    ) -> _Observation | None:
        """Move the tcp to `T_look` (when reachable, the move free and valid), observe with the wrist camera
        and estimate; the observation whose estimate is nearest the first (within `wrist_max_shift_m`). IK
        is seeded with `q_seed`, or the joints now when None."""
        cfg = self.config
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        ik = self.robot.ik(T_look, q_seed=q_now if q_seed is None else q_seed, frame="tcp")
        if not ik.success:
            return None
        _, hit = check_path(self.robot, scene, np.array([q_now, ik.q]), self.gripper_geometry, 0.0, True)
        if hit is not None:
            return None
        try:
            self.validator.validate_joint_move(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2, q_now)
        except UnsafeCommandError:
            return None
        t0 = time.perf_counter()
        self._emit("observe", "looking with the wrist camera", 0.35)
        try:
            self.arm.move_joints(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.info("wrist look refused: %s", exc)
            return None
        finally:
            timings["execute"] += time.perf_counter() - t0
        camera = self.camera
        try:
            self.camera = self.wrist_camera
            frame, ests = self._estimates_once(cmd.object_prompt, timings)
        except _Abort as exc:
            logger.info("wrist camera: %s", exc.message)
            return None
        finally:
            self.camera = camera
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        best = None
        for est in ests:
            target, _ = self._to_base(est, T_base_cam, "target")
            shift = float(np.linalg.norm(target.pose.t - obs.target.pose.t))
            if shift <= cfg.wrist_max_shift_m and (best is None or shift < best[0]):
                best = (shift, est, target)
        if best is None:
            logger.info("wrist camera: no %r within %.0f mm of the first view", cmd.object_prompt,
                        1e3 * cfg.wrist_max_shift_m)  # fmt: skip
            return None
        shift, est, target = best
        state["estimates"].append(est)
        state["T_base_cams"].append(T_base_cam)
        self._emit("estimate", f"wrist camera: the target is {1e3 * shift:.0f} mm from the first view", 0.4)
        return _Observation(obs.frame, est, target, obs.support, obs.points_base, obs.q_seen)

    def _wrist_mount(self) -> np.ndarray | None:
        """(4, 4) T_flange_cam of the wrist camera, learned once from a capture at the arm's joints now (the
        arm stands still while the loop observes; the frame's T_base_cam is the camera's hand-eye pose
        chained with the flange's), or None when that capture fails."""
        if self._T_flange_wrist_cam is None and self.wrist_camera is not None:
            try:
                frame = self.wrist_camera.capture()
            except CameraError as exc:
                logger.info("wrist camera mount not learned: %s", exc)
                return None
            if not isinstance(frame, RGBDFrame) or frame.T_base_cam is None:
                return None
            T_flange_base = invert_T(self.robot.fk(self.arm.joint_positions()))
            self._T_flange_wrist_cam = T_flange_base @ np.asarray(frame.T_base_cam, dtype=np.float64)
        return self._T_flange_wrist_cam

    def _held_scene(
        self, obs: _Observation, target: PlaceTarget, state: dict[str, Any], timings: dict[str, float]
    ) -> CollisionScene:
        """The scene for the moves while the object is held and for place planning: the observed points
        without the object's own (they leave with it), without the place surface's own (the floor of a bin,
        the deck of a pallet: the object is put down on them) and without the arm's; what this run already
        put down as boxes; the lower of the pick support and the place surface as the support plane."""
        t0 = time.perf_counter()
        P = obs.points_base
        T_surf = target.T_base_surface
        local = (P - T_surf[:3, 3]) @ T_surf[:3, :3]
        on_surface = np.all(np.abs(local[:, :2]) <= target.half_extents_xy_m, axis=1) & (
            np.abs(local[:, 2]) < _SURFACE_BAND_M
        )
        P = P[~on_surface]
        place_plane = Plane(T_surf[:3, 2], -float(T_surf[:3, 2] @ T_surf[:3, 3]))
        support = place_plane
        if obs.support is not None and _plane_z(obs.support) < _plane_z(place_plane):
            support = obs.support
        obstacles = [o for o in state["placed"] if not _overlaps(o, obs.target)]
        body = place_support_fixture(target)  # a conveyor's body below its belt: often not in this view
        if body is not None:
            obstacles.append(body)
        cfg = self.config.grasp or GraspConfig()
        scene = build_scene(
            obs.target, self.robot, self.gripper_geometry, obstacles, support, P, obs.q_seen, cfg
        )
        timings["plan"] += time.perf_counter() - t0
        return scene

    # ---------------------------------------------------------------------------------------- execution
    def _safe(self, what: str, fn: Callable[[], Any]) -> Any:
        """Run one arm command; a refusal by the validator or IK is an "ik_failed" attempt."""
        try:
            return fn()
        except UnreachableError as exc:
            raise _Abort("ik_failed", f"{what}: {exc}") from None
        except UnsafeCommandError as exc:
            raise _Abort("ik_failed", f"{what} refused by the validator: {exc}") from None

    def _robust_first(self, grasps: Sequence[Any], target: ObjectModel) -> list[Any]:
        """Parallel-jaw grasps whose pads sit at least half a pad plus `pad_depth_margin_m` inside the
        estimated box (measured from the face the approach enters) first, the rest after, each group in
        the planner's order: a grasp at the very rim of the estimate misses the object when the estimate's
        top is a centimetre high (the can's first tries)."""
        if self.gripper_kind != "parallel_jaw":
            return list(grasps)
        pad_half = 0.5 * float(getattr(self.gripper_geometry, "pad_size_m", (0, 0, 0.03))[2])
        corners = target.pose.corners()

        def deep(g: Any) -> bool:
            a = g.T_base_tcp[:3, 2]
            depth = float(np.max((corners - g.T_base_tcp[:3, 3]) @ -a))  # box extent behind the tcp
            return depth >= pad_half + self.config.pad_depth_margin_m

        flags = [deep(g) for g in grasps]
        return [g for g, f in zip(grasps, flags) if f] + [g for g, f in zip(grasps, flags) if not f]

    def _deepened(self, grasp: Any, target: ObjectModel, scene: CollisionScene) -> Any:
        """A parallel-jaw grasp whose pads reach less than half a pad plus `pad_depth_margin_m` into the
        estimated box (a rim grasp at the very top edge) moved that much deeper along its approach, when the
        deeper grasp has IK on the same branch and its approach from the pre-grasp is free (jaws open, the
        target included): pads at the rim's top close above it when the estimate is a centimetre high."""
        if self.gripper_kind != "parallel_jaw" or grasp.q is None or grasp.method == "section":
            return grasp  # (a section grasp's depth is planned from the seen surface, not from the box)
        pad_half = 0.5 * float(getattr(self.gripper_geometry, "pad_size_m", (0, 0, 0.03))[2])
        a = grasp.T_base_tcp[:3, 2]
        depth = float(np.max((target.pose.corners() - grasp.T_base_tcp[:3, 3]) @ -a))
        extra = min(pad_half + self.config.pad_depth_margin_m - depth, _MAX_DEEPEN_M)
        if extra <= 0.002:
            return grasp
        T = np.array(grasp.T_base_tcp)
        T[:3, 3] += extra * a
        ik = self.robot.ik(T, q_seed=grasp.q, frame="tcp")
        pre = self.robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
        if not (ik.success and pre.success) or float(np.max(np.abs(ik.q - grasp.q))) > 0.2:
            return grasp
        opening = float(grasp.opening_m)  # the margin is planned in (`_grasp_config`)
        _, hit = check_path(self.robot, scene, np.array([pre.q, ik.q]), self.gripper_geometry, opening, True)
        if hit is not None:
            return grasp
        retreat = np.array(grasp.T_base_retreat)
        retreat[:3, 3] += extra * a
        logger.info("grasp moved %.1f mm deeper along its approach", 1e3 * extra)
        return dataclasses.replace(grasp, T_base_tcp=T, q=ik.q, T_base_retreat=retreat)

    def _lines_continuous(self, grasp: Any) -> bool:
        """The approach (pre-grasp -> grasp) and the lift (grasp -> retreat) as the arm's `move_linear` runs
        them: IK every `_LINE_STEP_M` along the line, each seeded with the last; False when a joint jumps
        more than `_LINE_JUMP_RAD` between neighbours (a branch flip near a wrist singularity: the arm's
        validator refuses such a line halfway) or a point has no IK."""
        if grasp.q is None:
            return True
        pre = self.robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
        if not pre.success:
            return False
        for T0, T1, q0 in (
            (grasp.T_base_pregrasp, grasp.T_base_tcp, pre.q),
            (grasp.T_base_tcp, grasp.T_base_retreat, np.asarray(grasp.q, dtype=np.float64)),
        ):
            dp = np.asarray(T1[:3, 3]) - np.asarray(T0[:3, 3])
            n = max(2, math.ceil(float(np.linalg.norm(dp)) / _LINE_STEP_M))
            q_prev = np.asarray(q0, dtype=np.float64)
            for frac in np.linspace(1.0 / n, 1.0, n):
                T = np.array(T1, dtype=np.float64)
                T[:3, 3] = np.asarray(T0[:3, 3]) + frac * dp
                ik = self.robot.ik(T, q_seed=q_prev, frame="tcp")
                if not ik.success or float(np.max(np.abs(ik.q - q_prev))) > _LINE_JUMP_RAD:
                    return False
                q_prev = ik.q
        return True

    def _pressed(self, grasp: Any) -> Any:
        """A suction grasp pressed `compliance_m` into its face along the approach (the bellows give; the cup
        seals although the estimated face is a few millimetres off); other grasps as they are."""
        press = float(getattr(self.gripper_geometry, "compliance_m", 0.0))
        if grasp.method != "suction" or press <= 0 or grasp.q is None:
            return grasp
        T = np.array(grasp.T_base_tcp)
        T[:3, 3] += press * T[:3, 2]
        ik = self.robot.ik(T, q_seed=grasp.q, frame="tcp")
        if not ik.success or float(np.max(np.abs(ik.q - grasp.q))) > 0.2:  # 0.2 rad: another IK branch
            return grasp
        return dataclasses.replace(grasp, T_base_tcp=T, q=ik.q)

    def _grip_force(self) -> float:
        """Jaw force per finger (`grip_force_n`), or the suction cup's full holding force (vacuum on)."""
        if self.gripper_kind == "suction":
            return float(getattr(self.gripper_geometry, "max_force_n", self.config.grip_force_n))
        return self.config.grip_force_n

    def _open_for(self, grasp: Any) -> None:
        """Open the jaws to the grasp's planned opening, margin included (fully when the gripper cannot
        open part way, or for suction: release)."""
        open_to = getattr(self.gripper, "open_to", None)
        if self.gripper_kind == "parallel_jaw" and callable(open_to) and grasp.opening_m > 0:
            stroke = float(getattr(self.gripper_geometry, "stroke_m", 0.085))
            open_to(min(stroke, float(grasp.opening_m)))
            self._grip = _Grip()
        else:
            self._open_jaws()

    def _pick(self, grasp: Any, scene: CollisionScene, timings: dict[str, float]) -> float:
        cfg = self.config
        t0 = time.perf_counter()
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        ik = self.robot.ik(grasp.T_base_pregrasp, q_seed=grasp.q, frame="tcp")
        if not ik.success:
            timings["execute"] += time.perf_counter() - t0
            raise _Abort("ik_failed", f"pre-grasp: {ik.message}")
        grip = self.gripper_geometry
        W = np.array([q_now, ik.q])
        _, hit = check_path(self.robot, scene, W, grip, grasp.opening_m, True)
        if hit is not None:
            # The direct joint line collides: the grasp layer's detour (up, across, down), as for a place.
            try:
                W = free_move(
                    self.robot, scene, q_now, ik.q, grip, grasp.opening_m, None, None, MotionConfig(),
                    invert_T(grip.T_flange_tcp), False,
                )  # fmt: skip
            except NoFeasibleMotion:
                timings["execute"] += time.perf_counter() - t0
                raise _Abort("collision", f"path to the pre-grasp hits {hit.name}: {hit.reason}") from None
        detour = timed_trajectory(self.robot, W, MotionConfig()) if len(W) > 2 else None
        try:  # every move passes the validator before the first is sent
            if detour is not None:
                self.validator.validate_trajectory(detour, q_now)
            else:
                self.validator.validate_joint_move(
                    ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2, q_current=q_now
                )
            for T in (grasp.T_base_tcp, grasp.T_base_retreat):
                self.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except UnsafeCommandError as exc:
            timings["execute"] += time.perf_counter() - t0
            raise _Abort("ik_failed", f"the pick would be refused by the validator: {exc}") from None
        try:
            self._open_for(grasp)
            if detour is not None:
                self._safe("to pre-grasp (detour)", functools.partial(self.arm.follow, detour))
            else:
                self._safe(
                    "to pre-grasp",
                    lambda: self.arm.move_joints(ik.q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2),
                )
            self._safe(
                "approach",
                lambda: self.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2),
            )
            self._close_jaws()
            self._moving_closed()
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
                # A thin wall (a paper cup's 2 mm rim) stops the jaws below `min_jaw_width_m`: the floor is
                # then half the planned contact width.
                floor = min(self.config.min_jaw_width_m, 0.5 * float(getattr(grasp, "width_m", 0.0) or 0.0))
                held = held and width >= max(floor, _MIN_JAW_FLOOR_M)
            if not held:
                self._release_and_back_off(grasp)
                what = f"jaw width {1e3 * width:.1f} mm" if self.gripper_kind == "parallel_jaw" else "no seal"
                raise _Abort("slipped", f"nothing held after closing ({what})")
        finally:
            timings["verify"] += time.perf_counter() - t0
        return width

    def _go_home(self, q_home: np.ndarray) -> None:
        """Back to where the run started, out of the camera's view, before observing again. Joints whose
        range exceeds a turn go to the nearest equivalent angle (q + 2 pi k within the limits: the same
        pose), not back the long way (after a transfer the pan can be more than half a turn away)."""
        cfg = self.config
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        q_goal = np.array(q_home, dtype=np.float64)
        lower, upper = self.robot.joint_limits
        for j in range(len(q_goal)):
            options = [q_goal[j] + 2.0 * math.pi * k for k in (-1, 0, 1)]
            options = [v for v in options if lower[j] + 1e-3 <= v <= upper[j] - 1e-3] or [q_goal[j]]
            q_goal[j] = min(options, key=lambda v: abs(v - q_now[j]))
        # A joint more than 3 rad away (the validator takes at most half a turn per move) goes in two moves.
        steps = [0.5 * (q_now + q_goal), q_goal] if np.max(np.abs(q_goal - q_now)) > 3.0 else [q_goal]
        try:
            for q in steps:
                self.arm.move_joints(q, cfg.joint_speed_rad_s, cfg.joint_accel_rad_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.warning("could not return to the start configuration: %s", exc)

    def _release_and_back_off(self, grasp: Any) -> None:
        self._open_jaws()
        cfg = self.config
        try:
            self.arm.move_linear(grasp.T_base_retreat, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            logger.warning("could not back off after a failed grasp: %s", exc)

    def _reobserve(
        self,
        cmd: Command,
        obs: _Observation,
        grasp: Any,
        timings: dict[str, float],
        state: dict[str, Any],
        slip_check: bool = True,
    ) -> None:
        """After the lift: the object must no longer be seen where it stood (`slip_check`), and what is held
        must be the object named (`_wrong_object`; else it is put back and the attempt is "wrong_object").

        A candidate moved when its centre moved or its top rose by `moved_min_m`, or its lowest seen points
        are that high above the support: the lifted object seen in the hand is partly hidden by the gripper
        and its amodal box can reach down to the table (a 31 cm bottle lifted 34 cm was estimated 0.36 m
        tall, centre 31 mm from where it stood, top 56 mm higher)."""
        if not self.config.reobserve:
            return
        self._emit("verify", "re-observing", 0.8)
        before, support = obs.target, obs.support
        try:
            # Every candidate: one that fits the prompt better may have scored under the ratio before. A
            # frame without depth where the object stood shows nothing about it (`_depth_gone`).
            frame, ests = self._estimates(
                cmd.object_prompt, timings, 0.0, check=functools.partial(_depth_gone, obs=obs)
            )
        except _Abort as exc:
            if exc.reason == "camera_failed":  # no frame to judge the lift on: set it down, unverified
                self._set_down(grasp, f"the lift could not be verified: {exc.message}")
            if exc.reason != "not_found":
                raise
            # Nothing seen is no evidence by itself; the depth where the object stood is (the robot's own
            # readings kept: a hand in front of that place is something there): read as it was, the object
            # is still there; no longer (seen past it, or something in front: the hand, the object in it),
            # it is not where it stood.
            vacated = _vacated(self._last_raw_frame, obs)
            if vacated is None:
                self._set_down(
                    grasp, "the lift could not be verified: the re-observation sees no object and too few "
                    "depth readings where it stood",
                )  # fmt: skip
            if not vacated and slip_check:
                self._open_jaws()
                raise _Abort(
                    "slipped", "no object seen, but the depth where it stood still reads its surface"
                ) from None
            return
        t0 = time.perf_counter()
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        top_before = _top_height(before, support)
        heights = [_seen_heights(e, frame, support) for e in ests]  # each estimate's, once
        lowest = [-math.inf if h is None else float(np.percentile(h, 5.0)) for h in heights]

        def displacement(k: int) -> float:
            after = ObjectModel("target", ests[k].pose.transformed(T_base_cam))
            rise = _top_height(after, support) - top_before
            # it stood on the support: its lowest seen points that high above it rose at least that much
            return max(float(np.linalg.norm(after.pose.t - before.pose.t)), rise, lowest[k])

        # Any candidate still standing where the target stood means it was not lifted (those within
        # `candidate_ratio` of the best score, as fitted before every candidate was).
        best = max(float(getattr(e, "score", 1.0)) for e in ests)
        floor = self.config.candidate_ratio * best
        near = [k for k, e in enumerate(ests) if float(getattr(e, "score", 1.0)) >= floor]
        moves = [displacement(k) for k in near]
        est, moved = ests[near[int(np.argmin(moves))]], min(moves)
        wrong = self._wrong_object(cmd, obs, frame, ests, lowest)
        timings["verify"] += time.perf_counter() - t0
        state["estimates"].append(est)
        state["T_base_cams"].append(T_base_cam)
        if slip_check and moved < self.config.moved_min_m:
            self._open_jaws()
            raise _Abort("slipped", f"the object is still where it stood (moved {1e3 * moved:.0f} mm)")
        resting = self._resting_part(obs, grasp, ests, heights, T_base_cam) if slip_check else None
        if resting is not None:
            self._open_jaws()
            raise _Abort("slipped", resting)
        if wrong is not None:
            self._put_back(cmd, obs, grasp, frame, *wrong)

    def _resting_part(
        self,
        obs: _Observation,
        grasp: Any,
        ests: Sequence[Any],
        heights: Sequence[np.ndarray | None],
        T_base_cam: np.ndarray,
    ) -> str | None:
        """Why the lifted object is not off the support, or None: the candidate that moved most among those
        under the tcp (centre within half the object's largest extent plus `_HELD_XY_SLACK_M`, across) that
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
        tcp = np.asarray(self.robot.fk_tcp(self.arm.joint_positions()), dtype=np.float64)[:3, 3]
        reach = 0.5 * float(np.max(obs.target.pose.size)) + _HELD_XY_SLACK_M
        before = obs.target.pose.t
        under = [
            (float(np.linalg.norm(p.t - before)), k, float((p.t - before) @ up))
            for k, p in enumerate(e.pose.transformed(T_base_cam) for e in ests)
            if _across(p.t, tcp) <= reach
        ]
        # the held one rose: an object standing under the hand (a neighbour of a tall bottle) re-estimates
        # within about a centimetre or two of where it stood, up or down
        under = [u for u in under if u[2] >= 0.5 * self.config.moved_min_m]
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

    def _any_will_do(self, cmd: Command) -> bool:
        """Any object that fits the prompt will do: a plural command, or a stack of like things
        (`candidate_order` "top_first"); else the command names one object, and which one matters."""
        return cmd.plural or self.config.candidate_order == "top_first"

    def _wrong_object(
        self,
        cmd: Command,
        obs: _Observation,
        frame: RGBDFrame,
        ests: Sequence[Any],
        lowest_seen: Sequence[float],
    ) -> tuple[Any, Any, str] | None:
        """(held, the candidate that should have been picked, why) when the re-observation after the lift
        says the held object is not the one named; None when it is, or when it cannot tell (fails closed).

        The held object is the candidate nearest the tcp among those hanging under it (centre within half
        the object's largest extent plus `_HELD_XY_SLACK_M` of the tcp, across, and risen by `moved_min_m` or
        more from where the object stood: its box's centre, or its lowest seen points, `lowest_seen` per
        estimate: the 5th percentile of `_seen_heights`). The others count when they stand away from the
        tcp and from where the object was picked (`_SAME_PLACE_M`) and where the camera saw an object
        before the pick (`_stood_before`). Wrong: one of them fits the prompt clearly better
        (`wrong_object_margin`) and about as well as the object chosen before the pick (`_AS_WELL_AS_TOTAL`;
        only for a command naming one object with `candidate_order` "score"), or the prompt names a colour
        the held object's visible pixels clearly lack (`_COLOUR_ABSENT`) while one of them shows it
        (`_COLOUR_SHOWN`)."""
        if len(ests) < 2:
            return None
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        tcp = np.asarray(self.robot.fk_tcp(self.arm.joint_positions()), dtype=np.float64)[:3, 3]
        poses = [e.pose.transformed(T_base_cam) for e in ests]
        reach = 0.5 * float(np.max(obs.target.pose.size)) + _HELD_XY_SLACK_M
        # held: under the tcp, and risen from where the object stood (an object still on the table under the
        # lifted hand, a cup beside the bowl that was taken, is not in the hand): its box's centre rose, or
        # even its lowest seen points are that high above the support (seen in the air and partly behind
        # the jaws, a held object's amodal box can reach down to the table)
        rise = self.config.moved_min_m
        hanging = [
            k
            for k, p in enumerate(poses)
            if _across(p.t, tcp) <= reach
            and (p.t[2] - obs.target.pose.t[2] >= rise or lowest_seen[k] >= rise)
        ]
        if not hanging:
            return None  # the held object is not among the candidates: nothing to judge
        k_held = min(hanging, key=lambda k: float(np.linalg.norm(poses[k].t - tcp)))
        held = ests[k_held]
        standing = [
            e
            for k, (e, p) in enumerate(zip(ests, poses))
            if k != k_held
            and min(_across(p.t, tcp), _across(p.t, obs.target.pose.t)) > _SAME_PLACE_M
            and _stood_before(p, obs)
        ]
        if not standing:
            return None
        p_held = _probability(held)
        judged = [e for e in standing if math.isfinite(_probability(e))]
        if judged and math.isfinite(p_held) and not self._any_will_do(cmd):
            other = max(judged, key=_probability)
            # The held object is seen in the air and partly behind the jaws, so its own probability reads
            # low whatever it is; a standing one only counts when it also fits the words about as well as
            # the object chosen before the pick did (measured the same way, standing on the table)
            as_well = _total(other) >= _total(obs.estimate) - _AS_WELL_AS_TOTAL
            if as_well and _probability(other) - p_held > self.config.wrong_object_margin:
                return held, other, f"p {p_held:.2f} against {_probability(other):.2f}"
        colour = prompt_colour(cmd.object_prompt)
        if colour is None:
            return None

        def share(e: Any) -> float:
            return colour_share(frame.rgb, getattr(e, "mask", None), colour, frame.depth_m)

        s_held = share(held)
        shown = [(share(e), e) for e in standing]
        shown = [(s, e) for s, e in shown if math.isfinite(s)]
        if not (shown and math.isfinite(s_held) and s_held < _COLOUR_ABSENT):
            return None
        s_other, other = max(shown, key=lambda se: se[0])
        if s_other < _COLOUR_SHOWN:
            return None
        return held, other, f"{100 * s_held:.0f} % {colour} pixels against {100 * s_other:.0f} %"

    def _set_down(self, grasp: Any, why: str) -> None:
        """Set a lifted object down where it was picked when the lift cannot be verified (the lift line back
        down to the grasp pose, validated before it is sent, then open and back off), and end the attempt
        "camera_failed" with `why`; when the way down is refused the object stays held, and the message says
        so."""
        cfg = self.config
        try:
            for T in (grasp.T_base_tcp, grasp.T_base_retreat):
                self.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
            self.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            raise _Abort(
                "camera_failed", f"{why}; it could not be set down ({exc}): the gripper still holds it"
            ) from None
        self._release_and_back_off(grasp)
        raise _Abort("camera_failed", f"{why}; the object was set down where it was picked")

    def _put_back(
        self, cmd: Command, obs: _Observation, grasp: Any, frame: RGBDFrame, held: Any, other: Any, why: str
    ) -> None:
        """Put the wrong object back where it stood (the lift line back down to the grasp pose, validated
        before it is sent, then `_release_and_back_off`), and end the attempt "wrong_object"."""
        cfg = self.config
        T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
        seen = getattr(getattr(held, "attributes", None), "description", "") or "another object"
        # Where the one named stands, from the camera, relative to where the held one stood.
        stood_cam = transform_points(invert_T(T_base_cam), obs.target.pose.t[None])[0]
        where = positions(np.array([np.asarray(other.pose.t, dtype=np.float64), stood_cam]))[0]
        named = phrase(other, object_noun(cmd.object_prompt), where, T_base_cam)
        message = f"holding {seen}, not {cmd.object_prompt!r} ({why}): that is more likely {named}"
        self._emit("verify", f"wrong object: {message}; putting it back", 0.85)
        try:
            for T in (grasp.T_base_tcp, grasp.T_base_retreat):
                self.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
            self.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        except (UnreachableError, UnsafeCommandError) as exc:
            raise _Abort("wrong_object", f"{message}; it could not be put back ({exc}): still held") from None
        self._release_and_back_off(grasp)
        raise _Abort(
            "wrong_object",
            f"{message}; put it back where it stood",
            held_at=np.array(obs.target.pose.t),
            retry_at=np.array(other.pose.transformed(T_base_cam).t),
        )

    def _pick_place(
        self,
        obs: _Observation,
        grasp: Any,
        target: PlaceTarget,
        scene: CollisionScene,
        held_scene: CollisionScene,
        timings: dict[str, float],
        state: dict[str, Any],
        attempt: int,
        cmd: Command,
    ) -> float:
        t0 = time.perf_counter()
        q_now = np.asarray(self.arm.joint_positions(), dtype=np.float64)
        carried = self._carried(obs)
        try:
            place = plan_place(
                carried,
                grasp,
                target,
                self.robot,
                self.gripper_geometry,
                obstacles=tuple(state["placed"]),
                q_seed=grasp.q,
                config=_PLACE_CONFIG,
                scene=held_scene,
            )
            motion = plan_pick_place(
                self.robot, grasp, place, carried, scene, held_scene, self.gripper_geometry, q_now
            )
        except NoFeasiblePlace as exc:  # the cause, when there is one: e.g. the pallet pattern's misfit
            cause = f" ({exc.__cause__})" if exc.__cause__ is not None else ""
            raise _Abort("no_feasible_grasp", f"{exc}{cause}") from None
        except NoFeasibleMotion as exc:
            reason = "ik_failed" if "IK" in exc.reason else "collision"
            raise _Abort(reason, str(exc)) from None
        finally:
            timings["plan"] += time.perf_counter() - t0
        q = q_now
        for seg in motion.segments:  # the whole motion passes the validator before anything moves
            try:
                self.validator.validate_trajectory(seg.trajectory, q)
            except UnsafeCommandError as exc:
                raise _Abort("ik_failed", f"{seg.name} would be refused by the validator: {exc}") from None
            q = np.asarray(seg.trajectory.q[-1], dtype=np.float64)
        state["place"] = place
        t0 = time.perf_counter()
        width = 0.0
        try:
            self._open_for(grasp)
            for seg in motion.segments:
                self._emit("place" if seg.holding else "execute", f"segment {seg.name}", 0.5, attempt)
                self._moving_closed()
                self._safe(seg.name, functools.partial(self.arm.follow, seg.trajectory))
                if seg.name == "approach":
                    self._close_jaws()
                elif seg.name == "lift":
                    timings["execute"] += time.perf_counter() - t0
                    width = self._verify_held(grasp, timings)
                    t0 = time.perf_counter()
                    # Held is the object named? (a slip shows at the descent: no slip check here)
                    self._reobserve(cmd, obs, grasp, timings, state, slip_check=False)
                    t0 = time.perf_counter()
                elif seg.name == "descend":
                    if not self.gripper.grasp_detected():
                        self._open_jaws()
                        raise _Abort("slipped", "the object was lost during the transfer")
                    self._open_for(grasp)
        finally:
            timings["execute"] += time.perf_counter() - t0
        placed = ObjectModel(
            f"placed {len(state['placed']) + 1}",
            Pose9D(place.T_base_obj[:3, :3], place.T_base_obj[:3, 3], carried.pose.size),
        )
        state["placed"].append(placed)
        return width

    def _success_message(self, cmd: Command, state: dict[str, Any]) -> str:
        n = len(state["attempts"])
        what = cmd.object_prompt if not cmd.plural else f"{state['done']} x {cmd.object_prompt}"
        where = cmd.target if cmd.target != "object" else cmd.target_prompt
        verb = "picked" if cmd.action == "pick" else f"placed ... on/in the {where}:"
        return f"{verb} {what!r} after {n} attempt(s)"


#: Prior families that hold things inside them (a place "on" one of them puts the object in).
_CONTAINERS = ("bowl", "cup", "mug", "bin", "basket", "bucket", "pot", "tray")
#: Place candidates examined (the planner's default 200 are all within ~0.3 m of the preferred point: a belt
#: with one carton already at its centre had no free spot among them).
_PLACE_CONFIG = PlaceConfig(max_candidates=2000)
#: Jaws closed narrower than this held nothing, whatever the planned width (the 2F-85 class reads 0 when
#: closed on nothing; the sim's gripper reads negative) [m].
_MIN_JAW_FLOOR_M = 0.001
#: `_lines_continuous` solves IK every this much along a line [m] ...
_LINE_STEP_M = 0.005
#: ... and a joint changing more than this between neighbours is a jump, not a motion [rad] (away from
#: singularities a 5 mm tcp step moves no joint more than ~0.03 rad; the validator allows 0.2 per waypoint).
_LINE_JUMP_RAD = 0.2
#: A candidate this close to where the object of a failed round stood is that object [m]: a slipped grasp
#: nudges it a few centimetres; two tabletop objects stand at least ~10 cm centre to centre.
_SAME_PLACE_M = 0.06
#: The most a grasp is moved deeper along its approach by `_deepened` [m].
_MAX_DEEPEN_M = 0.03
#: Observed points this close to a place surface are the surface itself [m] (sensor noise at 1-2 m).
_SURFACE_BAND_M = 0.02
#: After the lift, the held object's centre lies across from the tcp by at most half its largest extent (a
#: grasp on a side face) plus this: the estimate of an object half hidden in the hand is off by 1-2 cm [m].
_HELD_XY_SLACK_M = 0.03
#: Seen points this close to the support rest on it (depth noise and the plane fit put an object's points
#: on the support within about a centimetre of the plane); a held object's part rests on the support when
#: this share of its mask's points, and at least this many, lie there.
_RESTING_M = 0.015
_RESTING_SHARE = 0.01
_RESTING_MIN_POINTS = 3
#: A candidate stood there before the pick when the pick's observed points, above the support by more than
#: this, lie inside its box grown by this: the fitted box's faces are ~1 cm off the surface it was fitted to,
#: and the table's own points stay under it [m] ...
_STOOD_MARGIN_M = 0.01
#: ... at least this many of them: the observation is thinned to `max_scene_points` (every 7th point of 640 x
#: 480), which leaves ~200 on the top of a 5 cm object at 0.8 m (fx 600 px); 20 is a corner of one [-].
_STOOD_MIN_POINTS = 20
#: A held object whose visible pixels are under this share of the colour the prompt names clearly is not of
#: that colour: one that is keeps far more even half hidden by the jaws (a green bottle with a white label),
#: while a few percent are edge pixels blended with what lies behind [-] ...
_COLOUR_ABSENT = 0.03
#: ... while another candidate shows it on at least this share: that colour, not a printed detail [-].
_COLOUR_SHOWN = 0.25


#: A re-observation is trusted only with depth readings on at least this share of the pixels that had one
#: where the object stood in the pick's view (the object's box, projected): the lifted object, the hand and
#: the table behind them all give readings; a depth dropout (a sensor fault, a saturated projector) does not.
_DEPTH_KEPT_SHARE = 0.5
#: A depth reading within this of where the pick's view saw the object's surface is that surface (sensor
#: noise at ~1 m is a few millimetres to 1 cm; a lifted object is at least 10 cm from where it stood) [m].
_SAME_SURFACE_M = 0.02
#: The object is still where it stood when at least this share of the readings there are its surface [-].
_STILL_SHARE = 0.5


def _mode_text(mode: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in mode) + ")"


def _box_window(frame: RGBDFrame, pose_base: Pose9D) -> tuple[int, int, int, int] | None:
    """Pixel window (u0, u1, v0, v1), end-exclusive, of a box in base seen in `frame`: the bounds of its
    projected corners, clipped to the image; None when a corner lies behind the camera or the window is
    empty."""
    T_cam_base = invert_T(np.asarray(frame.T_base_cam, dtype=np.float64))
    X = transform_points(T_cam_base, pose_base.corners())
    if np.any(X[:, 2] <= 0):
        return None
    K = frame.intrinsics
    u = K.fx * X[:, 0] / X[:, 2] + K.cx
    v = K.fy * X[:, 1] / X[:, 2] + K.cy
    u0, u1 = max(0, math.floor(u.min())), min(K.width, math.ceil(u.max()) + 1)
    v0, v1 = max(0, math.floor(v.min())), min(K.height, math.ceil(v.max()) + 1)
    return None if u0 >= u1 or v0 >= v1 else (u0, u1, v0, v1)


def _depth_gone(frame: RGBDFrame, obs: _Observation) -> str | None:
    """Why a re-observation frame cannot be trusted about the object of `obs`, or None: where the object stood
    (its box, projected), it has depth readings on fewer than `_DEPTH_KEPT_SHARE` of the pixels the pick's
    view had them on."""
    before_win, now_win = _box_window(obs.frame, obs.target.pose), _box_window(frame, obs.target.pose)
    if before_win is None:
        return None  # the pick's view did not hold the box: nothing to compare with
    u0, u1, v0, v1 = before_win
    had = int(np.count_nonzero(valid_depth_mask(obs.frame.depth_m[v0:v1, u0:u1])))
    if had == 0:
        return None
    has = 0
    if now_win is not None:
        u0, u1, v0, v1 = now_win
        has = int(np.count_nonzero(valid_depth_mask(frame.depth_m[v0:v1, u0:u1])))
    if has >= _DEPTH_KEPT_SHARE * had:
        return None
    return f"the depth is gone where the object stood ({has} readings there, the pick's view had {had})"


def _vacated(frame: RGBDFrame | None, obs: _Observation) -> bool | None:
    """Does the depth of `frame` show that the object of `obs` left where it stood? The pick's observed points
    of the object (inside its box, above the support, as `_stood_before`) are looked up in `frame`: True when
    fewer than `_STILL_SHARE` of the readings there lie on its surface (within `_SAME_SURFACE_M`: seen past
    it, or something in front of it); False when more do (it is still there); None when there are fewer
    than `_STOOD_MIN_POINTS` readings to tell."""
    if frame is None or frame.T_base_cam is None:
        return None
    P = obs.points_base
    pose = obs.target.pose
    local = (P - pose.t) @ pose.R
    grow = _STOOD_MARGIN_M if obs.support is not None else 0.0
    inside = np.all(np.abs(local) <= 0.5 * np.asarray(pose.size) + grow, axis=1)
    if obs.support is not None:
        inside &= P @ np.asarray(obs.support.normal) + obs.support.offset_m > _STOOD_MARGIN_M
    X = transform_points(invert_T(np.asarray(frame.T_base_cam, dtype=np.float64)), P[inside])
    X = X[X[:, 2] > 0]
    K = frame.intrinsics
    u = np.rint(K.fx * X[:, 0] / X[:, 2] + K.cx).astype(np.int64)
    v = np.rint(K.fy * X[:, 1] / X[:, 2] + K.cy).astype(np.int64)
    in_image = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    depth = frame.depth_m[v[in_image], u[in_image]]
    read = valid_depth_mask(depth)
    if int(np.count_nonzero(read)) < _STOOD_MIN_POINTS:
        return None
    still = np.abs(depth[read] - X[in_image][read, 2]) <= _SAME_SURFACE_M
    return bool(np.mean(still) < _STILL_SHARE)


def _aim_camera(T_base_tcp: np.ndarray, T_tcp_cam: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(4, 4) the tcp pose `T_base_tcp` moved sideways, its orientation kept, so that the optical axis (+z) of
    the camera it carries at `T_tcp_cam` passes through `point` (3,) in base [m]."""
    T_cam = np.asarray(T_base_tcp, dtype=np.float64) @ np.asarray(T_tcp_cam, dtype=np.float64)
    z = T_cam[:3, 2]
    d = np.asarray(point, dtype=np.float64) - T_cam[:3, 3]
    out = np.array(T_base_tcp, dtype=np.float64)
    out[:3, 3] += d - (d @ z) * z  # the part of the offset across the axis
    return out


def _size_ratio(size: np.ndarray, ref_sorted: np.ndarray) -> float:
    """The largest factor between a box's sorted extents and the reference's (1 for the same size)."""
    a = np.maximum(np.sort(np.asarray(size, dtype=np.float64)), 1e-6)
    b = np.maximum(np.asarray(ref_sorted, dtype=np.float64), 1e-6)
    return float(np.max(np.maximum(a / b, b / a)))


#: A standing candidate "fits about as well" as the object chosen before the pick when its score total is
#: within this of the chosen one's: T ln 2 of the grounder's calibration (`confidence.ConfidenceModel`),
#: odds within a factor of two.
_AS_WELL_AS_TOTAL = ConfidenceModel().temperature * math.log(2.0)


def _total(est: Any) -> float:
    """The grounder's score total of an estimate (`grounding.score.total_of_score`; -inf without a score)."""
    s = float(getattr(est, "score", float("nan")))
    return -math.inf if math.isnan(s) else float(total_of_score(min(max(s, 0.0), 1.0)))


def _score(obs: _Observation) -> float:
    """The grounding score of an observation's estimate (1 for estimators without one)."""
    return float(getattr(obs.estimate, "score", 1.0))


def _plane_z(plane: Plane) -> float:
    """Height of a plane where it passes under the base origin, along its normal [m]."""
    return float(-plane.offset_m)


def _height(obj: ObjectModel, support: Plane | None) -> float:
    """Extent of the object's box along the support normal (base +z without one) [m]."""
    up = np.array([0.0, 0.0, 1.0]) if support is None else np.asarray(support.normal)
    return float(np.abs(obj.pose.R.T @ up) @ obj.pose.size)


def _seen_heights(est: Any, frame: RGBDFrame, support: Plane | None) -> np.ndarray | None:
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


def _top_height(obj: ObjectModel, support: Plane | None) -> float:
    """Height of the top of the object's box along the support normal [m]."""
    up = np.array([0.0, 0.0, 1.0]) if support is None else np.asarray(support.normal)
    return float(obj.pose.t @ up + 0.5 * _height(obj, support))


def _at_target(obj: ObjectModel, target: PlaceTarget) -> bool:
    """The object's centre is above the target's surface, within its footprint (it was put there)."""
    T = target.T_base_surface
    local = T[:3, :3].T @ (obj.pose.t - T[:3, 3])
    return bool(np.all(np.abs(local[:2]) <= target.half_extents_xy_m) and -0.02 < local[2] < 1.0)


def _across(a: np.ndarray, b: np.ndarray) -> float:
    """Horizontal distance of two base-frame points (across base +z) [m]."""
    return float(np.linalg.norm((np.asarray(a) - np.asarray(b))[:2]))


def _probability(est: Any) -> float:
    """The estimate's calibrated probability of being the object named (NaN when not computed)."""
    return float(getattr(est, "probability", math.nan))


def _stood_before(pose_base: Pose9D, obs: _Observation) -> bool:
    """The camera saw an object inside this box before the pick: `_STOOD_MIN_POINTS` of the pick's observed
    points in it (grown by `_STOOD_MARGIN_M`), above its support plane (without a plane: in the box)."""
    P = obs.points_base
    local = (P - pose_base.t) @ pose_base.R
    grow = _STOOD_MARGIN_M if obs.support is not None else 0.0
    inside = np.all(np.abs(local) <= 0.5 * np.asarray(pose_base.size) + grow, axis=1)
    if obs.support is not None:
        inside &= P @ np.asarray(obs.support.normal) + obs.support.offset_m > _STOOD_MARGIN_M
    return int(np.count_nonzero(inside)) >= _STOOD_MIN_POINTS


def _overlaps(a: ObjectModel, b: ObjectModel) -> bool:
    """The two boxes' centres lie within each other's half extents (the same object seen twice)."""
    d = np.abs(a.pose.t - b.pose.t)
    return bool(np.all(d <= np.maximum(a.pose.size, b.pose.size) / 2.0))
