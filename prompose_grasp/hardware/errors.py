"""Errors of the hardware adapters; all are `PromposeError`s (see `prompose_grasp.errors`).

The device faults are the robot layer's (`prompose_grasp.robot.interfaces`), re-exported here: the MuJoCo arm
and the pick loop raise and catch the same classes as the UR adapter without importing this package."""

from __future__ import annotations

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.robot.interfaces import (
    ConnectionLostError,
    EmergencyStopError,
    GripperError,
    MotionFailedError,
    ProtectiveStopError,
    SafetyStopError,
)

__all__ = [
    "CalibrationError",
    "ConnectionLostError",
    "EmergencyStopError",
    "GripperError",
    "MotionFailedError",
    "ProtectiveStopError",
    "SafetyStopError",
]


class CalibrationError(InvalidInputError):
    """A hand-eye calibration file is missing, unreadable or does not hold one rigid transform."""
