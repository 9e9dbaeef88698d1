"""The exit status of every `prompose-grasp` command (the package docstring says what each means)."""

from __future__ import annotations

#: Exit status of a `run` that ended in a typed outcome that is neither a success nor a device fault ...
EXIT_FAILED = 1


#: ... of bad input (`main`) ...
EXIT_BAD_INPUT = 2


#: ... and of a device fault (module docstring).
EXIT_DEVICE_FAULT = 3


def exit_status(reason: str) -> int:
    """The exit status of a `run` outcome with this reason (module docstring)."""
    from prompose_grasp.pipeline.outcome import DEVICE_FAULT_REASONS

    if reason == "success":
        return 0
    return EXIT_DEVICE_FAULT if reason in DEVICE_FAULT_REASONS else EXIT_FAILED
