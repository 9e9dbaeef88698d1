"""Hardware adapters behind the robot-layer interfaces: a UR arm over RTDE, Robotiq and IO-suction grippers,
RealSense / Azure Kinect / recorded-sequence cameras, hand-eye calibration files, and `run_command` (the
`prompose-grasp run` command). Set-up, frames and safety: docs/hardware.md.

Only this package imports the hardware SDKs (ur_rtde, pyrealsense2, pyk4a), and only when a device
connects: `import prompose_grasp.hardware` works without any of them, and a missing one raises
`MissingDependencyError` naming the extra to install.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.hardware.calibration import HandEyeCalibration, load_calibration
    from prompose_grasp.hardware.cameras import (
        AzureKinectCamera,
        CalibratedCamera,
        RealSenseCamera,
        RecordedSequenceCamera,
        frame_from_kinect,
        frame_from_realsense,
        intrinsics_from_realsense,
        write_intrinsics,
    )
    from prompose_grasp.hardware.errors import (
        CalibrationError,
        ConnectionLostError,
        EmergencyStopError,
        GripperError,
        MotionFailedError,
        ProtectiveStopError,
        SafetyStopError,
    )
    from prompose_grasp.hardware.robotiq import ROBOTIQ_PORT, RobotiqConfig, RobotiqGripper
    from prompose_grasp.hardware.run import CellSpec, DryRunGripper, RunResult, run_command
    from prompose_grasp.hardware.suction import IOSuctionGripper, SuctionIOConfig
    from prompose_grasp.hardware.ur_rtde import (
        RECEIVE_VARIABLES,
        RTDE_PORT,
        URRtdeArm,
        URRtdeConfig,
        URRtdeLinks,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.hardware.calibration": (
            "HandEyeCalibration",
            "load_calibration",
        ),
        "prompose_grasp.hardware.cameras": (
            "AzureKinectCamera",
            "CalibratedCamera",
            "RealSenseCamera",
            "RecordedSequenceCamera",
            "frame_from_kinect",
            "frame_from_realsense",
            "intrinsics_from_realsense",
            "write_intrinsics",
        ),
        "prompose_grasp.hardware.errors": (
            "CalibrationError",
            "ConnectionLostError",
            "EmergencyStopError",
            "GripperError",
            "MotionFailedError",
            "ProtectiveStopError",
            "SafetyStopError",
        ),
        "prompose_grasp.hardware.robotiq": (
            "ROBOTIQ_PORT",
            "RobotiqConfig",
            "RobotiqGripper",
        ),
        "prompose_grasp.hardware.run": (
            "CellSpec",
            "DryRunGripper",
            "RunResult",
            "run_command",
        ),
        "prompose_grasp.hardware.suction": (
            "IOSuctionGripper",
            "SuctionIOConfig",
        ),
        "prompose_grasp.hardware.ur_rtde": (
            "RECEIVE_VARIABLES",
            "RTDE_PORT",
            "URRtdeArm",
            "URRtdeConfig",
            "URRtdeLinks",
        ),
    },
    submodules=(
        "calibration",
        "cameras",
        "errors",
        "places",
        "robotiq",
        "run",
        "suction",
        "ur_rtde",
    ),
)

__all__ = [
    "RECEIVE_VARIABLES",
    "ROBOTIQ_PORT",
    "RTDE_PORT",
    "AzureKinectCamera",
    "CalibratedCamera",
    "CalibrationError",
    "CellSpec",
    "ConnectionLostError",
    "DryRunGripper",
    "EmergencyStopError",
    "GripperError",
    "HandEyeCalibration",
    "IOSuctionGripper",
    "MotionFailedError",
    "ProtectiveStopError",
    "RealSenseCamera",
    "RecordedSequenceCamera",
    "RobotiqConfig",
    "RobotiqGripper",
    "RunResult",
    "SafetyStopError",
    "SuctionIOConfig",
    "URRtdeArm",
    "URRtdeConfig",
    "URRtdeLinks",
    "frame_from_kinect",
    "frame_from_realsense",
    "intrinsics_from_realsense",
    "load_calibration",
    "run_command",
    "write_intrinsics",
]
