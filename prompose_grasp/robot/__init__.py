"""Robot layer: UR arms from one DH table, FK/IK (closed form, mink, Pinocchio), device interfaces.

>>> from prompose_grasp.robot import load_robot
>>> robot = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.15])  # doctest: +SKIP
>>> result = robot.ik(robot.fk_tcp(q), q_seed=q_now, frame="tcp")  # doctest: +SKIP
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.robot.fake import HOME_Q, FakeArm, FakeGripper
    from prompose_grasp.robot.ik import IK_METHODS, IKConfig, IKResult
    from prompose_grasp.robot.interfaces import (
        Arm,
        Device,
        Gripper,
        JointCommand,
        JointTrajectory,
        LinearCommand,
        RGBDCamera,
        RGBDFrame,
    )
    from prompose_grasp.robot.model import RobotModel, load_robot
    from prompose_grasp.robot.mujoco_model import add_arm_to_spec, add_support_plane, ur_mjspec
    from prompose_grasp.robot.trajectory import LinearTrajectory, joint_trajectory, linear_trajectory
    from prompose_grasp.robot.ur_models import JOINT_NAMES, UR_MODELS, URSpec, get_ur_spec, known_robots
    from prompose_grasp.robot.urdf import ur_urdf
    from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.robot.fake": (
            "HOME_Q",
            "FakeArm",
            "FakeGripper",
        ),
        "prompose_grasp.robot.ik": (
            "IK_METHODS",
            "IKConfig",
            "IKResult",
        ),
        "prompose_grasp.robot.interfaces": (
            "Arm",
            "Device",
            "Gripper",
            "JointCommand",
            "JointTrajectory",
            "LinearCommand",
            "RGBDCamera",
            "RGBDFrame",
        ),
        "prompose_grasp.robot.model": (
            "RobotModel",
            "load_robot",
        ),
        "prompose_grasp.robot.mujoco_model": (
            "add_arm_to_spec",
            "add_support_plane",
            "ur_mjspec",
        ),
        "prompose_grasp.robot.trajectory": (
            "LinearTrajectory",
            "joint_trajectory",
            "linear_trajectory",
        ),
        "prompose_grasp.robot.ur_models": (
            "JOINT_NAMES",
            "UR_MODELS",
            "URSpec",
            "get_ur_spec",
            "known_robots",
        ),
        "prompose_grasp.robot.urdf": ("ur_urdf",),
        "prompose_grasp.robot.validator": (
            "CommandValidator",
            "ValidatorConfig",
        ),
    },
    submodules=(
        "fake",
        "ik",
        "interfaces",
        "kinematics",
        "model",
        "mujoco_model",
        "real_numbers",
        "trajectory",
        "ur_models",
        "urdf",
        "validator",
    ),
)

__all__ = [
    "HOME_Q",
    "IK_METHODS",
    "JOINT_NAMES",
    "UR_MODELS",
    "Arm",
    "CommandValidator",
    "Device",
    "FakeArm",
    "FakeGripper",
    "Gripper",
    "IKConfig",
    "IKResult",
    "JointCommand",
    "JointTrajectory",
    "LinearCommand",
    "LinearTrajectory",
    "RGBDCamera",
    "RGBDFrame",
    "RobotModel",
    "URSpec",
    "ValidatorConfig",
    "add_arm_to_spec",
    "add_support_plane",
    "get_ur_spec",
    "joint_trajectory",
    "known_robots",
    "linear_trajectory",
    "load_robot",
    "ur_mjspec",
    "ur_urdf",
]
