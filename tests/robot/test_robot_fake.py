"""FakeArm / FakeGripper behave like a backend at the interface; RGBDFrame validates its contents."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError, UnsafeCommandError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.robot import (
    HOME_Q,
    Arm,
    FakeArm,
    FakeGripper,
    Gripper,
    JointCommand,
    JointTrajectory,
    RGBDFrame,
    load_robot,
)


def test_fake_arm_implements_arm_and_needs_a_connection():
    arm = FakeArm()
    assert isinstance(arm, Arm)
    with pytest.raises(DeviceNotConnectedError, match="connect"):
        arm.joint_positions()
    with arm:
        assert arm.is_connected
        np.testing.assert_array_equal(arm.joint_positions(), HOME_Q)
    assert not arm.is_connected


def test_move_joints_sends_the_validated_command_and_refusals_change_nothing():
    robot = load_robot("ur5e", tcp_offset=[0, 0, 0.1])
    with FakeArm(robot) as arm:
        target = HOME_Q + 0.2
        sent = arm.move_joints(target, speed=1.0, accel=1.0)
        assert isinstance(sent, JointCommand) and arm.sent == [sent]
        np.testing.assert_array_equal(arm.joint_positions(), target)
        np.testing.assert_allclose(arm.tcp_pose(), robot.fk_tcp(target), atol=0)
        bad = target.copy()
        bad[2] = 4.0
        with pytest.raises(UnsafeCommandError):
            arm.move_joints(bad, speed=1.0, accel=1.0)
        np.testing.assert_array_equal(arm.joint_positions(), target)
        assert len(arm.sent) == 1


def test_move_linear_reaches_the_pose():
    with FakeArm() as arm:
        T = arm.tcp_pose()
        T[:3, 3] += [0.05, -0.03, 0.04]
        arm.move_linear(T, speed=0.1, accel=0.5)
        # Closed-form IK is exact to float64 rounding.
        np.testing.assert_allclose(arm.tcp_pose(), T, atol=1e-9)


def test_follow_ends_at_the_last_waypoint():
    with FakeArm() as arm:
        s = np.linspace(0, 1, 51)[1:]
        q = HOME_Q + (3 * s**2 - 2 * s**3)[:, None] * 0.3
        sent = arm.follow(JointTrajectory(t_s=2.0 * s, q=q))
        np.testing.assert_array_equal(arm.joint_positions(), q[-1])
        assert len(sent) == 50
        arm.stop()
        assert arm.stopped


def test_fake_gripper():
    gripper = FakeGripper(object_width_m=0.04)
    assert isinstance(gripper, Gripper)
    with gripper:
        assert gripper.width() == pytest.approx(0.085)
        assert gripper.close(force=50.0) is True
        assert gripper.grasp_detected() and gripper.width() == pytest.approx(0.04)
        gripper.open()
        assert not gripper.grasp_detected()
        with pytest.raises(InvalidInputError, match="grip force"):
            gripper.close(force=1000.0)
    with FakeGripper() as empty:
        assert empty.close(force=50.0) is False and empty.width() == 0.0


def test_rgbd_frame_checks_shapes_and_dtypes():
    K = CameraIntrinsics(fx=500.0, fy=500.0, cx=31.5, cy=23.5, width=64, height=48)
    rgb = np.zeros((48, 64, 3), np.uint8)
    depth = np.ones((48, 64), np.float32)
    frame = RGBDFrame(rgb=rgb, depth_m=depth, intrinsics=K, timestamp_s=1.5, T_base_cam=np.eye(4))
    assert frame.T_base_cam is not None and frame.T_base_cam.shape == (4, 4)
    with pytest.raises(InvalidInputError, match="uint8"):
        RGBDFrame(rgb=rgb.astype(np.float32), depth_m=depth, intrinsics=K, timestamp_s=0.0)
    with pytest.raises(InvalidInputError, match="float32 metres"):
        RGBDFrame(rgb=rgb, depth_m=depth[:, :10], intrinsics=K, timestamp_s=0.0)
