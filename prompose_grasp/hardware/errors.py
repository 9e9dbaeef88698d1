"""Errors of the hardware adapters; all are `PromposeError`s (see `prompose_grasp.errors`)."""

from __future__ import annotations

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError, PromposeError

__all__ = [
    "CalibrationError",
    "ConnectionLostError",
    "EmergencyStopError",
    "GripperError",
    "MotionFailedError",
    "ProtectiveStopError",
    "SafetyStopError",
]


class ConnectionLostError(DeviceNotConnectedError):
    """The link to a device dropped while it was in use. The adapter took its stop path (a stop command where
    the control link still answered) and marked itself disconnected; `reconnect()` or `connect()` again."""


class MotionFailedError(PromposeError):
    """The controller refused a move, never started it, or did not finish it in time; the adapter sent a
    stop. The link is still up (check the pendant for the reason: a program running, a mode change)."""


class SafetyStopError(PromposeError):
    """The controller stopped the arm on its own (a safety function). Nothing more is sent until it is
    cleared on the teach pendant; then call `reconnect()`."""


class ProtectiveStopError(SafetyStopError):
    """Protective stop (a collision, a force limit, a safeguard input)."""


class EmergencyStopError(SafetyStopError):
    """Emergency stop (an e-stop button or the safety system)."""


class GripperError(PromposeError):
    """A gripper refused a command, answered something unexpected, or did not finish in time."""


class CalibrationError(InvalidInputError):
    """A hand-eye calibration file is missing, unreadable or does not hold one rigid transform."""
