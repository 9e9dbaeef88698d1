"""What a pick-and-place run returns (`PickOutcome`) and what it reports while it runs (`ProgressEvent`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, get_args

import numpy as np

from prompose_grasp.errors import InvalidInputError

if TYPE_CHECKING:  # types of the fields only: importing them here would load perception and grasp eagerly
    from prompose_grasp.grasp.place import PlacePose
    from prompose_grasp.grasp.types import Grasp
    from prompose_grasp.pipeline.command import Command
    from prompose_grasp.pipeline.seams import ObjectEstimate

__all__ = [
    "DEVICE_FAULT_REASONS",
    "REASONS",
    "STAGES",
    "AttemptRecord",
    "PickOutcome",
    "ProgressEvent",
    "Reason",
]

#: Why a run ended. "success" is the only good one; the others say which stage gave up ("not_understood":
#: the command text could not be parsed; the message says what was understood and gives examples).
#: "ambiguous": several objects fit the prompt about equally well, so none was touched; the message
#: describes each (colour, kind, where, size) and the outcome's `estimates` are theirs, best first.
#: "wrong_object": after the lift, what is held is not the object named (another one fits the prompt
#: clearly better); it was put back where it stood, and the message names both.
#: Device faults (`robot.interfaces`), after the loop's stop path (the message says what it did and in what
#: state it left the gripper): "protective_stop" (the controller's safety stopped the arm: a collision, a
#: force limit), "emergency_stop" (nothing more was sent to the arm or the gripper), "connection_lost" (a
#: device's link dropped; nothing more was sent to the arm), "motion_failed" (the controller refused or did
#: not finish a move), "gripper_failed" (the gripper refused or did not finish a command).
Reason = Literal[
    "success",
    "not_found",
    "no_feasible_grasp",
    "ik_failed",
    "slipped",
    "collision",
    "timeout",
    "camera_failed",
    "not_understood",
    "ambiguous",
    "wrong_object",
    "protective_stop",
    "emergency_stop",
    "connection_lost",
    "motion_failed",
    "gripper_failed",
]
REASONS: tuple[str, ...] = get_args(Reason)
#: The reasons that are device faults (a run that ends in one needs a person at the cell).
DEVICE_FAULT_REASONS: tuple[str, ...] = (
    "protective_stop",
    "emergency_stop",
    "connection_lost",
    "motion_failed",
    "gripper_failed",
)
#: Stages a `ProgressEvent` can name, in the order a run goes through them.
STAGES: tuple[str, ...] = ("parse", "observe", "estimate", "plan", "execute", "verify", "place", "done")


@dataclass(frozen=True)
class ProgressEvent:
    """One step of a run, for a live display.

    Attributes:
        stage: one of `STAGES`.
        message: what happens, in words ("grasp 1/10 (antipodal, quality 0.82)").
        fraction: rough overall progress in [0, 1].
        attempt: 1-based attempt number (0 before the first attempt).
    """

    stage: str
    message: str
    fraction: float
    attempt: int = 0

    def __post_init__(self) -> None:
        if self.stage not in STAGES:
            raise InvalidInputError(
                f"ProgressEvent.stage must be one of {', '.join(STAGES)}, got {self.stage!r}"
            )
        if not 0.0 <= self.fraction <= 1.0:
            raise InvalidInputError(f"ProgressEvent.fraction must be in [0, 1], got {self.fraction}")


@dataclass(frozen=True, eq=False)
class AttemptRecord:
    """One grasp attempt: which grasp, how it ended.

    Attributes:
        attempt: 1-based attempt number.
        grasp: the `prompose_grasp.grasp.Grasp` executed (or tried).
        result: "success" or a failure `Reason` of this attempt.
        message: details in words.
        gripper_width_m: jaw opening after closing [m] (0 for suction / not closed).
    """

    attempt: int
    grasp: Grasp
    result: Reason
    message: str
    gripper_width_m: float = 0.0


@dataclass(frozen=True, eq=False)
class PickOutcome:
    """How a pick-and-place run ended. Returned, never raised, for every expected failure.

    Attributes:
        reason: one of `REASONS`; "success" when the object was picked (and placed, for place commands).
        success: reason == "success".
        message: what happened, in words (the last failure's details when it failed).
        command: the parsed `Command`, or None when the text could not be parsed.
        estimates: every `Estimate` of the target used, in order (camera frame of its frame); for "ambiguous"
            the contenders', best first.
        T_base_cams: (4, 4) `T_base_cam` of the frame of each estimate [m].
        attempts: the `AttemptRecord`s, in order.
        grasp: the grasp that held the object, or None.
        place: the `PlacePose` used, or None.
        timings_s: wall time per stage {"observe", "estimate", "plan", "execute", "verify", "total"} [s].
        objects_done: objects picked (and placed) in this run: 0 or 1, more for a plural command ("move the
            cartons ...": one object after the other until none is left or `PickConfig.max_objects`).
    """

    reason: Reason
    message: str
    command: Command | None = None
    estimates: tuple[ObjectEstimate, ...] = ()
    T_base_cams: tuple[np.ndarray, ...] = ()
    attempts: tuple[AttemptRecord, ...] = ()
    grasp: Grasp | None = None
    place: PlacePose | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    objects_done: int = 0

    def __post_init__(self) -> None:
        if self.reason not in REASONS:
            raise InvalidInputError(
                f"PickOutcome.reason must be one of {', '.join(REASONS)}, got {self.reason!r}"
            )

    @property
    def success(self) -> bool:
        return self.reason == "success"

    @property
    def estimate(self) -> ObjectEstimate | None:
        """The last estimate of the target, or None."""
        return self.estimates[-1] if self.estimates else None

    @property
    def grasps_tried(self) -> tuple[Grasp, ...]:
        return tuple(a.grasp for a in self.attempts)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no arrays of images)."""
        est = self.estimate
        return {
            "success": self.success,
            "reason": self.reason,
            "message": self.message,
            "command": None
            if self.command is None
            else {
                "text": self.command.text,
                "action": self.command.action,
                "object_prompt": self.command.object_prompt,
                "target": self.command.target,
                "target_prompt": self.command.target_prompt,
            },
            "place": None
            if self.place is None
            else {"T_base_obj": np.asarray(self.place.T_base_obj).tolist(), "reason": self.place.reason},
            "objects_done": self.objects_done,
            "n_estimates": len(self.estimates),
            "estimate_cam": None if est is None else {**est.pose.to_dict(), "prior": est.prior.name},
            "attempts": [
                {
                    "attempt": a.attempt,
                    "result": a.result,
                    "message": a.message,
                    "method": getattr(a.grasp, "method", None),
                    "quality": None if a.grasp is None else float(a.grasp.quality),
                    "gripper_width_m": a.gripper_width_m,
                }
                for a in self.attempts
            ],
            "timings_s": dict(self.timings_s),
        }
