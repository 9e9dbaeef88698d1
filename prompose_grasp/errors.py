"""The error hierarchy. Every error the library raises on purpose is a `PromposeError`.

Messages say what was wrong and what is accepted, so a user can fix the call without reading the source.
Subclasses also derive from the matching built-in (`ValueError`, `LookupError`, `ImportError`) so that code
written against the standard library's conventions keeps working.
"""

from __future__ import annotations

from collections.abc import Iterable


class PromposeError(Exception):
    """Root of every error raised on purpose by prompose_grasp."""


class InvalidInputError(PromposeError, ValueError):
    """An argument has the wrong shape, dtype, units or values (NaN, non-rotation, bad intrinsics, ...)."""


class UnknownNameError(PromposeError, LookupError):
    """A name (robot, gripper, IoU mode, config variant, ...) is not one of the known choices."""

    def __init__(self, kind: str, name: object, known: Iterable[str]):
        self.kind = kind
        self.name = name
        self.known = tuple(known)
        super().__init__(f"unknown {kind} {name!r}; known: {', '.join(self.known)}")

    def __str__(self) -> str:  # LookupError would otherwise repr() the message
        return str(self.args[0])


class MissingDependencyError(PromposeError, ImportError):
    """An optional dependency is needed for this call; the message names the extra that installs it."""


class UnsafeCommandError(PromposeError):
    """A motion command was refused before it reached an arm (limits, step, speed, workspace, NaN)."""


class UnreachableError(PromposeError):
    """No joint configuration reaches the requested pose within tolerance."""


class CameraError(PromposeError):
    """A camera failed to deliver a frame."""


class DeviceNotConnectedError(PromposeError, RuntimeError):
    """A device (arm, gripper, camera) was used before `connect()` or after `disconnect()`."""


class DeviceFault(PromposeError):
    """A device failed while in use: a safety stop, a dropped link, a refused or unfinished move, a gripper
    fault. The kinds are defined with the device interfaces (`prompose_grasp.robot.interfaces`); the command
    line exits with status 3 on any of them (`prompose_grasp.cli`)."""


class ObjectNotFoundError(PromposeError):
    """No object in the frame matches the prompt (grounding found no candidate)."""


class AmbiguousObjectError(PromposeError, LookupError):
    """Several objects in the frame fit the prompt about equally well, so none is chosen.

    Attributes:
        prompt: the prompt as given.
        estimates: the estimates of the objects that fit (best first); each has its `probability` and its
            measured `attributes`, from which a caller can describe them to the user.
    """

    def __init__(self, prompt: str, estimates: Iterable[object], message: str | None = None):
        self.prompt = prompt
        self.estimates = tuple(estimates)
        super().__init__(
            message
            or f"{len(self.estimates)} objects fit {prompt!r} about equally well; name the one you mean "
            "more narrowly (colour, size or position)"
        )

    def __str__(self) -> str:
        return str(self.args[0])


class NoFeasibleGrasp(PromposeError):
    """Every grasp candidate was rejected; `rejected` counts the candidates per reason ("stroke", "ik",
    "collision_object", ...), and the message lists them."""

    def __init__(self, rejected: dict[str, int], n_candidates: int, what: str = "grasp"):
        self.rejected = dict(rejected)
        self.n_candidates = int(n_candidates)
        self.timings_ms: dict[str, float] = {}  # the planner's stage timings, when it sets them
        counts = ", ".join(f"{k}: {v}" for k, v in sorted(self.rejected.items(), key=lambda kv: -kv[1]))
        super().__init__(
            f"no feasible {what} among {self.n_candidates} candidates (rejected: {counts or 'none'})"
        )


class NoFeasiblePlace(NoFeasibleGrasp):
    """Every place pose candidate was rejected; `rejected` counts them per reason."""

    def __init__(self, rejected: dict[str, int], n_candidates: int):
        super().__init__(rejected, n_candidates, what="place pose")


class NoFeasibleMotion(PromposeError):
    """A pick-and-place motion segment could not be made collision-free and within limits; `segment` names
    it and `reason` says what was hit."""

    def __init__(self, segment: str, reason: str):
        self.segment = segment
        self.reason = reason
        super().__init__(f"motion segment {segment!r} is not feasible: {reason}")
