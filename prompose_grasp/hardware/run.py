"""One language command on a real cell (UR arm + gripper + calibrated camera), or its dry run.

```
spec = CellSpec(robot="ur5e", host="192.168.1.10", gripper="robotiq", camera="realsense",
                calibration="cell/hand_eye.yaml", dry_run=True)
result = run_command(spec, "pick up the red mug")
print("\n".join(result.moves))           # what was sent (dry run: what would have been sent)
```

A dry run builds the same `PickAndPlace` with the same robot model, gripper geometry, validator and camera,
but drives a `FakeArm` (validated, instant, starting where the real arm stands when `host` is given, read
over a receive-only RTDE link, else at `HOME_Q`) and a gripper that assumes every close holds. Nothing is
sent to the arm or the gripper. The scene never changes under a dry run, so the re-observation after the lift
is off.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.grasp import get_gripper
from prompose_grasp.grasp.grippers import GripperGeometry, ParallelJawGeometry, SuctionCupGeometry
from prompose_grasp.hardware.calibration import load_calibration
from prompose_grasp.hardware.cameras import (
    AzureKinectCamera,
    CalibratedCamera,
    RealSenseCamera,
    RecordedSequenceCamera,
)
from prompose_grasp.hardware.places import load_place_targets
from prompose_grasp.hardware.robotiq import ROBOTIQ_PORT, RobotiqGripper
from prompose_grasp.hardware.suction import IOSuctionGripper
from prompose_grasp.hardware.ur_rtde import RtdeLinks, URRtdeArm, URRtdeConfig, URRtdeLinks
from prompose_grasp.pipeline.cell import Cell, CellConfig, make_cell, register_cell
from prompose_grasp.pipeline.outcome import PickOutcome, ProgressEvent
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.recorder import Recorder
from prompose_grasp.robot.fake import HOME_Q, FakeArm
from prompose_grasp.robot.interfaces import (
    Arm,
    Gripper,
    JointCommand,
    JointTrajectory,
    LinearCommand,
    RGBDCamera,
)
from prompose_grasp.robot.model import RobotModel, load_robot

__all__ = [
    "GRIPPERS",
    "CellSpec",
    "DryRunGripper",
    "HardwareCellConfig",
    "RecordingArm",
    "RecordingGripper",
    "RunResult",
    "build_camera",
    "build_hardware_cell",
    "run_command",
]

logger = logging.getLogger(__name__)

#: Gripper names of the command line -> the planner's gripper kind.
GRIPPERS = {"robotiq": "parallel_jaw", "suction": "suction"}

#: Camera names of the command line (anything else is a recorded-sequence folder).
CAMERAS = ("realsense", "kinect")


@dataclass(frozen=True)
class CellSpec:
    """What is attached.

    Attributes:
        robot: UR model name ("ur5e", ...).
        host: the controller's address (required unless `dry_run`).
        gripper: "robotiq" or "suction".
        camera: "realsense", "kinect", or a folder of recorded NNNNNN-color/depth.png frames.
        calibration: hand-eye file (T_base_cam or T_flange_cam; see `hardware.calibration`).
        dry_run: plan and print every move, send none.
        places: place-target file (bin, table, pallet, conveyor in `base`; see `hardware.places`), or None:
            then place commands that name a fixture end `not_found` (objects seen in the image, "in the
            white bowl", still work).
    """

    robot: str
    host: str | None
    gripper: str
    camera: str
    calibration: str | Path
    dry_run: bool = False
    places: str | Path | None = None

    def __post_init__(self) -> None:
        if self.gripper not in GRIPPERS:
            raise UnknownNameError("gripper", self.gripper, GRIPPERS)
        if not self.dry_run and not self.host:
            raise InvalidInputError("--host is required to drive the arm (or use --dry-run)")
        if self.camera not in CAMERAS and not Path(self.camera).is_dir():
            raise UnknownNameError("camera (or a folder of recorded frames)", self.camera, CAMERAS)


@dataclass(frozen=True)
class RunResult:
    """The pipeline's outcome and what went to the devices, in order (dry run: what would have gone).

    Attributes:
        outcome: the pipeline's `PickOutcome`.
        moves: one line per arm command and gripper action, in order.
        arm_commands: the validated arm commands themselves (`JointCommand`, `LinearCommand`,
            `JointTrajectory`), in order.
        dry_run: nothing was sent.
    """

    outcome: PickOutcome
    moves: tuple[str, ...]
    arm_commands: tuple[Any, ...]
    dry_run: bool


def _fmt(v: ArrayLike, digits: int = 4) -> str:
    return "[" + ", ".join(f"{x:.{digits}f}" for x in np.asarray(v, dtype=np.float64).ravel()) + "]"


def describe(command: JointCommand | LinearCommand | JointTrajectory) -> str:
    """One line for a validated command (SI units)."""
    if isinstance(command, JointCommand):
        return (
            f"moveJ  q = {_fmt(command.q)} rad, speed {command.speed_rad_s:.3f} rad/s, "
            f"accel {command.accel_rad_s2:.3f} rad/s^2"
        )
    if isinstance(command, LinearCommand):
        from prompose_grasp.geometry.se3 import pose_vector_from_T

        p = pose_vector_from_T(command.T_base_tcp)
        return (
            f"moveL  tcp xyz = {_fmt(p[:3])} m, rotvec = {_fmt(p[3:])} rad, "
            f"speed {command.speed_m_s:.3f} m/s, accel {command.accel_m_s2:.3f} m/s^2"
        )
    return (
        f"servoJ {len(command)} waypoints over {command.duration_s:.2f} s, "
        f"ending at q = {_fmt(command.q[-1])} rad"
    )


class RecordingArm(Arm):
    """Delegates to `arm`; appends one line per command that went through to `log`, the command to `sent`."""

    def __init__(self, arm: Arm, log: list[str]):
        self.arm = arm
        self.log = log
        self.sent: list[JointCommand | LinearCommand | JointTrajectory] = []

    def _record(self, command):
        self.sent.append(command)
        self.log.append(describe(command))
        return command

    def connect(self) -> None:
        self.arm.connect()
        super().connect()

    def disconnect(self) -> None:
        self.arm.disconnect()
        super().disconnect()

    def joint_positions(self) -> np.ndarray:
        return self.arm.joint_positions()

    def tcp_pose(self) -> np.ndarray:
        return self.arm.tcp_pose()

    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        return self._record(self.arm.move_joints(q, speed, accel))

    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        return self._record(self.arm.move_linear(T_base_tcp, speed, accel))

    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        return self._record(self.arm.follow(trajectory))

    @property
    def senses_contact(self) -> bool:
        return bool(self.arm.senses_contact)

    def move_linear_until_contact(
        self, T_base_tcp: ArrayLike, speed: float, accel: float, max_force_n: float
    ) -> bool:
        reached = self.arm.move_linear_until_contact(T_base_tcp, speed, accel, max_force_n)
        self._record(LinearCommand(np.asarray(T_base_tcp, dtype=np.float64), float(speed), float(accel)))
        self.log[-1] += f" (guarded at {max_force_n:g} N: {'reached' if reached else 'stopped on contact'})"
        return reached

    def stop(self) -> None:
        self.arm.stop()
        self.log.append("stop")


class RecordingGripper(Gripper):
    """Delegates to `gripper` and appends one line per open / close to `log`."""

    def __init__(self, gripper: Gripper, log: list[str]):
        self.gripper = gripper
        self.log = log

    def connect(self) -> None:
        self.gripper.connect()
        super().connect()

    def disconnect(self) -> None:
        self.gripper.disconnect()
        super().disconnect()

    def open(self) -> None:
        self.gripper.open()
        self.log.append("gripper open")

    def close(self, force: float) -> bool:
        held = self.gripper.close(force)
        self.log.append(f"gripper close, force {force:.1f} N -> {'holding' if held else 'nothing held'}")
        return held

    def grasp_detected(self) -> bool:
        return self.gripper.grasp_detected()

    def width(self) -> float:
        return self.gripper.width()


class DryRunGripper(Gripper):
    """A gripper for dry runs: nothing is sent, and every close is assumed to hold the object.

    `width()` reports the gripper's stroke while open and `held_width_m` after a close (jaws stopped on
    something that wide; by default half the stroke). A suction cup has no jaws: its stroke is 0 m, and so is
    every width it reports.
    """

    def __init__(self, geometry: GripperGeometry, held_width_m: float | None = None):
        if not isinstance(geometry, (ParallelJawGeometry, SuctionCupGeometry)):
            raise InvalidInputError(
                f"geometry must be a ParallelJawGeometry or SuctionCupGeometry, got {type(geometry).__name__}"
            )
        self.geometry = geometry
        self.max_width_m = float(geometry.stroke_m)
        self.held_width_m = 0.5 * self.max_width_m if held_width_m is None else float(held_width_m)
        self._holding = False

    def open(self) -> None:
        self._require()
        self._holding = False

    def close(self, force: float) -> bool:
        self._require()
        if not (np.isfinite(force) and force > 0):
            raise InvalidInputError(f"grip force must be finite and > 0 [N], got {force!r}")
        self._holding = True
        return True

    def grasp_detected(self) -> bool:
        self._require()
        return self._holding

    def width(self) -> float:
        self._require()
        return self.held_width_m if self._holding else self.max_width_m


def build_camera(name: str) -> RGBDCamera:
    """ "realsense", "kinect", or a recorded-sequence folder."""
    if name == "realsense":
        return RealSenseCamera()
    if name == "kinect":
        return AzureKinectCamera()
    if Path(name).is_dir():
        return RecordedSequenceCamera(name)
    raise UnknownNameError("camera (or a folder of recorded frames)", name, CAMERAS)


def _current_q(host: str, links: Any = None) -> np.ndarray:
    """The arm's joints over a receive-only link (a dry run sends nothing, so no control link)."""
    from prompose_grasp.errors import DeviceNotConnectedError

    links = links or URRtdeLinks()
    try:
        receive = links.receive(host)
    except RuntimeError as exc:
        raise DeviceNotConnectedError(f"could not read the arm at {host} (RTDE port 30004): {exc}") from exc
    try:
        return np.asarray(receive.getActualQ(), dtype=np.float64)
    finally:
        receive.disconnect()


@dataclass(frozen=True, eq=False)
class HardwareCellConfig(CellConfig):
    """The real cell `spec` describes (or its dry run), for the cell factory (`pipeline.make_cell`).

    Attributes:
        spec: what is attached (`CellSpec`).
        q_start: dry run only: start here instead of reading the arm (or `HOME_Q` without a host).
        robot_model: override the model built from `spec.robot` and the gripper's TCP.
        links: the RTDE link factory (default: the real ur_rtde, `URRtdeLinks`).
        robotiq_port: the Robotiq URCap's port on the controller.
    """

    spec: CellSpec
    q_start: ArrayLike | None = None
    robot_model: RobotModel | None = None
    links: RtdeLinks | None = None
    robotiq_port: int = ROBOTIQ_PORT


@register_cell(HardwareCellConfig)
def build_hardware_cell(config: HardwareCellConfig) -> Cell:
    """The arm (UR over RTDE, or a `FakeArm` for a dry run), the gripper, the calibrated camera and the place
    targets of `config.spec`; arm and gripper record every command (`RecordingArm.log`, `.sent`)."""
    spec = config.spec
    calibration = load_calibration(spec.calibration)
    place_targets = load_place_targets(spec.places) if spec.places is not None else {}
    geometry = get_gripper(GRIPPERS[spec.gripper])
    robot = config.robot_model or load_robot(spec.robot, tcp_offset=geometry.T_flange_tcp)
    log: list[str] = []
    if spec.dry_run:
        q_start = config.q_start
        if q_start is None:
            q_start = _current_q(spec.host, config.links) if spec.host else HOME_Q
        inner_arm: Arm = FakeArm(robot, q_initial=q_start)
        inner_gripper: Gripper = DryRunGripper(geometry)
    else:
        assert spec.host is not None
        suction = isinstance(geometry, SuctionCupGeometry)
        ur = URRtdeArm(spec.host, robot, config=URRtdeConfig(use_io=suction), links=config.links)
        inner_arm = ur
        inner_gripper = IOSuctionGripper(ur) if suction else RobotiqGripper(spec.host, config.robotiq_port)
    camera = CalibratedCamera(
        build_camera(spec.camera), calibration, T_base_flange=lambda: robot.fk(inner_arm.joint_positions())
    )
    logger.info(
        "cell: %s with %s, camera %s (%s), place targets: %s",
        robot.name,
        spec.gripper,
        spec.camera,
        calibration.key,
        ", ".join(place_targets) or "none",
    )
    return Cell(
        RecordingArm(inner_arm, log),
        RecordingGripper(inner_gripper, log),
        camera,
        robot,
        geometry,
        place_targets,
    )


def run_command(
    spec: CellSpec,
    command: str,
    estimator: Any = None,
    config: PickConfig | None = None,
    on_event: Callable[[ProgressEvent], None] | None = None,
    q_start: ArrayLike | None = None,
    robot_model: RobotModel | None = None,
    links: RtdeLinks | None = None,
    robotiq_port: int = ROBOTIQ_PORT,
    recorder: Recorder | None = None,
) -> RunResult:
    """Run `command` on the cell of `spec` (or dry-run it); returns the outcome and the moves in order.

    Args:
        estimator: default `ProMPose.default()` (recording its grounding and estimates into `recorder`).
        recorder: records the run (`prompose_grasp.viz.RerunRecorder`); None records nothing.
        config: `PickConfig` (a dry run turns `reobserve` off).
        q_start, robot_model, links, robotiq_port: as `HardwareCellConfig`.
    """
    from prompose_grasp.perception.estimator import ProMPose

    cell = make_cell(HardwareCellConfig(spec, q_start, robot_model, links, robotiq_port))
    config = config or PickConfig()
    if spec.dry_run:
        config = replace(config, reobserve=False)
    estimator = estimator or ProMPose.default(recorder=recorder)
    logger.info("%s %r", "dry run of" if spec.dry_run else "running", command)
    arm = cell.arm
    assert isinstance(arm, RecordingArm)
    with cell:
        pnp = PickAndPlace.for_cell(cell, estimator, config=config, on_event=on_event, recorder=recorder)
        outcome = pnp.run(command)
    return RunResult(outcome, tuple(arm.log), tuple(arm.sent), spec.dry_run)
