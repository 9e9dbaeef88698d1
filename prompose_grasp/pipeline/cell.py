"""The cell: the arm, gripper, cameras and place fixtures one loop runs on (`Cell`), and the one factory
that builds it from a backend's config (`make_cell`, lerobot's `make_robot_from_config` pattern).

Each backend registers a builder for its config type: the simulator (`sim.cell.SimCellConfig`) and the
real cell (`hardware.run.HardwareCellConfig`). Both then build the loop the same way:

```
with make_cell(config) as cell:
    outcome = PickAndPlace.for_cell(cell, estimator, pick_config).run("put the mug in the bin")
```
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, TypeVar

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.grasp.grippers import GripperGeometry
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.robot.interfaces import Arm, Gripper, RGBDCamera
from prompose_grasp.robot.model import RobotModel

__all__ = ["Cell", "CellConfig", "make_cell", "register_cell"]


@dataclass(frozen=True, eq=False)
class Cell:
    """The devices and models of one work cell; a context manager that connects the devices (arm, gripper,
    camera, wrist camera, in that order) and disconnects them in reverse.

    Attributes:
        arm: the arm (validates its own commands).
        gripper: the gripper `gripper_geometry` describes. A parallel-jaw gripper with an `open_to(width_m)`
            method opens only as wide as each grasp needs (`PickConfig.open_margin_m`); otherwise fully.
        camera: a fixed (or any calibrated) camera whose frames carry `T_base_cam`.
        robot: the arm's `RobotModel` with the gripper's tcp offset.
        gripper_geometry: the gripper's geometry (`ParallelJawGeometry` or `SuctionCupGeometry`).
        place_targets: {kind: PlaceTarget} fixtures for place commands ("bin", "table", "pallet", "conveyor").
        wrist_camera: a camera on the arm (frames with `T_base_cam` at capture), or None.
    """

    arm: Arm
    gripper: Gripper
    camera: RGBDCamera
    robot: RobotModel
    gripper_geometry: GripperGeometry
    place_targets: Mapping[str, PlaceTarget] = field(default_factory=dict)
    wrist_camera: RGBDCamera | None = None
    _connected: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, init=False, repr=False)

    def __post_init__(self) -> None:
        targets = dict(self.place_targets or {})
        for kind, target in targets.items():
            if not isinstance(target, PlaceTarget):
                raise InvalidInputError(f"place_targets[{kind!r}] must be a PlaceTarget, got {type(target)}")
        object.__setattr__(self, "place_targets", targets)

    def __enter__(self) -> Cell:
        with contextlib.ExitStack() as stack:
            for device in (self.arm, self.gripper, self.camera, self.wrist_camera):
                if device is not None:
                    stack.enter_context(device)
            object.__setattr__(self, "_connected", stack.pop_all())
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._connected.__exit__(exc_type, exc, tb)


class CellConfig:
    """The base of a backend's cell config (a frozen dataclass of what is attached); `make_cell` builds the
    `Cell` with the builder registered for its type."""


C = TypeVar("C", bound=CellConfig)
_BUILDERS: dict[type[CellConfig], Callable[[Any], Cell]] = {}


def register_cell(config_type: type[C]) -> Callable[[Callable[[C], Cell]], Callable[[C], Cell]]:
    """Decorator: `builder(config) -> Cell` builds the cells of `config_type` (and its subclasses)."""

    def register(builder: Callable[[C], Cell]) -> Callable[[C], Cell]:
        _BUILDERS[config_type] = builder
        return builder

    return register


def make_cell(config: CellConfig) -> Cell:
    """The `Cell` a backend's config describes (not yet connected: use it in a `with` block)."""
    for cls in type(config).__mro__:
        builder = _BUILDERS.get(cls)
        if builder is not None:
            return builder(config)
    known = sorted(c.__name__ for c in _BUILDERS) or ["none registered: import sim.cell or hardware.run"]
    raise UnknownNameError("cell config", type(config).__name__, known)
