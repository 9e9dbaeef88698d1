"""The cell: the arm, gripper, cameras and place fixtures one loop runs on (`Cell`).

A `Cell` is what `PickAndPlace` needs of the hardware, whether simulated or real; it is built in one place
for each backend by `make_cell` (`pipeline.cell_factory`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp.grippers import GripperGeometry
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.robot.interfaces import Arm, Gripper, RGBDCamera
from prompose_grasp.robot.model import RobotModel

__all__ = ["Cell"]


@dataclass(frozen=True, eq=False)
class Cell:
    """The devices and models of one work cell.

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

    def __post_init__(self) -> None:
        targets = dict(self.place_targets or {})
        for kind, target in targets.items():
            if not isinstance(target, PlaceTarget):
                raise InvalidInputError(f"place_targets[{kind!r}] must be a PlaceTarget, got {type(target)}")
        object.__setattr__(self, "place_targets", targets)
