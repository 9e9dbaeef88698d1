"""What every stage of the loop works with (`Loop`): the cell's devices and models, the estimator, the
settings, the command validator, the progress callback and the recorder."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from prompose_grasp.grasp.grippers import GripperGeometry
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.pipeline.cell import Cell
from prompose_grasp.pipeline.config import PickConfig
from prompose_grasp.pipeline.outcome import ProgressEvent
from prompose_grasp.pipeline.seams import Estimator
from prompose_grasp.recorder import NULL_RECORDER, Recorder
from prompose_grasp.robot.interfaces import Arm, Gripper, RGBDCamera
from prompose_grasp.robot.model import RobotModel
from prompose_grasp.robot.validator import CommandValidator

__all__ = ["Loop"]


class Loop:
    """The cell, the estimator, the settings, the validator every planned motion is checked against, and the
    progress callback, the recorder (`prompose_grasp.recorder`; the no-op one by default); and what the loop
    learns about the cell once (the wrist camera's mount)."""

    def __init__(
        self,
        cell: Cell,
        estimator: Estimator,
        config: PickConfig,
        validator: CommandValidator,
        on_event: Callable[[ProgressEvent], None] | None = None,
        recorder: Recorder | None = None,
    ):
        self.cell = cell
        self.estimator = estimator
        self.config = config
        self.validator = validator
        self.on_event = on_event
        self.recorder = recorder or NULL_RECORDER
        #: (4, 4) T_flange_cam of the wrist camera, learned at the first wrist look (`wrist_look.wrist_mount`)
        self.T_flange_wrist_cam: np.ndarray | None = None

    @property
    def arm(self) -> Arm:
        return self.cell.arm

    @property
    def gripper(self) -> Gripper:
        return self.cell.gripper

    @property
    def camera(self) -> RGBDCamera:
        return self.cell.camera

    @property
    def wrist_camera(self) -> RGBDCamera | None:
        return self.cell.wrist_camera

    @property
    def robot(self) -> RobotModel:
        return self.cell.robot

    @property
    def gripper_geometry(self) -> GripperGeometry:
        return self.cell.gripper_geometry

    @property
    def place_targets(self) -> Mapping[str, PlaceTarget]:
        return self.cell.place_targets

    def camera_name(self, camera: RGBDCamera) -> str:
        """ "wrist" for the wrist camera, else "fixed" (the names frames are recorded under)."""
        return "wrist" if camera is self.wrist_camera else "fixed"

    def joints(self) -> np.ndarray:
        """(6,) the arm's joint positions now [rad], float64."""
        return np.asarray(self.arm.joint_positions(), dtype=np.float64)

    def emit(self, stage: str, message: str, fraction: float, attempt: int = 0) -> None:
        """A `ProgressEvent` to the callback (when there is one), `fraction` clipped to [0, 1]; the stage and
        message to the recorder."""
        self.recorder.stage(stage, message)
        if self.on_event is not None:
            self.on_event(ProgressEvent(stage, message, min(max(fraction, 0.0), 1.0), attempt))
