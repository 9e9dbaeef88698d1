"""Device faults: the outcome each ends a run in, and the stop path after one.

After an e-stop or a lost link nothing more is sent to the arm (an e-stopped controller takes no motion, a
person may be at the cell, and a dropped link may not carry a command); after the other faults the arm is
told to stop. The gripper is opened only where that cannot drop anything: closed on an object that still
rests on its support (before the lift) it is opened (not after an e-stop); closed on an object that may be in
the air it stays closed, and the outcome's message says so, as it says every state it leaves the gripper in.
"""

from __future__ import annotations

from prompose_grasp.pipeline.hand import open_jaws
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.outcome import Reason
from prompose_grasp.pipeline.record import RunRecord
from prompose_grasp.robot.interfaces import (
    ConnectionLostError,
    EmergencyStopError,
    GripperError,
    MotionFailedError,
    SafetyStopError,
)

__all__ = ["DEVICE_FAULTS", "fault_reason", "stop_after_fault"]

#: Device faults and the outcome each ends a run in, the first class that matches (an e-stop is a safety stop
#: too; any other stop the controller's safety functions make is protective).
_FAULTS: tuple[tuple[type[Exception], Reason], ...] = (
    (EmergencyStopError, "emergency_stop"),
    (SafetyStopError, "protective_stop"),
    (ConnectionLostError, "connection_lost"),
    (MotionFailedError, "motion_failed"),
    (GripperError, "gripper_failed"),
)
DEVICE_FAULTS: tuple[type[Exception], ...] = tuple(c for c, _ in _FAULTS)


def fault_reason(exc: BaseException) -> Reason:
    """The outcome reason of a device fault (one of `DEVICE_FAULTS`)."""
    return next(reason for cls, reason in _FAULTS if isinstance(exc, cls))


def stop_after_fault(loop: Loop, run: RunRecord, reason: Reason, exc: BaseException) -> str:
    """The stop path after a device fault (see the module's docstring); returns the outcome's message: the
    fault, what was sent after it, and the state the gripper is left in."""
    notes = [str(exc)]
    if reason in ("emergency_stop", "connection_lost"):
        notes.append("nothing more was sent to the arm")
    else:
        try:
            loop.arm.stop()
            notes.append("the arm was told to stop")
        except Exception as stop_exc:  # the stop path goes on, and reports whatever the device raised
            notes.append(f"the arm's stop command failed ({type(stop_exc).__name__}: {stop_exc})")
    grip = run.grip
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
            open_jaws(loop, run)
            notes.append("the gripper was opened (the object rests on its support)")
        except Exception as open_exc:  # as above
            notes.append(
                f"the gripper is still closed: opening it failed ({type(open_exc).__name__}: {open_exc})"
            )
    return "; ".join(notes)
