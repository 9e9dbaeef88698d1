"""SimArm's protective stop: a contact force over the limit stops the arm with the robot layer's
`ProtectiveStopError` (the UR adapter's), like a UR controller's force limit."""

from __future__ import annotations

import numpy as np
import pytest
from test_sim_arm import R_DOWN, _world

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.hardware import ProtectiveStopError as HardwareProtectiveStop
from prompose_grasp.robot.interfaces import ProtectiveStopError
from sim.arm import PROTECTIVE_STOP_FORCE_N, SimArm

pytestmark = pytest.mark.sim


def test_free_motion_feels_no_force_and_the_limit_is_validated():
    with _world() as world, SimArm(world) as arm:
        T0 = arm.tcp_pose()
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.15]), 0.25, 1.0)
        assert arm.max_external_force_n == 0.0  # nothing touched the robot: no contact, no force
        assert not arm.protective_stopped
        with pytest.raises(InvalidInputError, match="protective_stop_force_n"):
            SimArm(world, protective_stop_force_n=-1.0)


def test_driving_the_fingers_into_the_table_is_a_protective_stop():
    # The table top is at base z = 0 (base 0.75 m up, the table 0.75 m tall); the line ends 5 cm below it.
    with _world() as world, SimArm(world) as arm:
        T0 = arm.tcp_pose()
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.15]), 0.25, 1.0)
        with pytest.raises(ProtectiveStopError, match="table") as info:
            arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], -0.05]), 0.1, 1.0)
        assert isinstance(info.value, HardwareProtectiveStop)  # the very class the UR adapter raises
        assert arm.protective_stopped and arm.max_external_force_n > PROTECTIVE_STOP_FORCE_N
        # It stopped on the table: the tcp (between the pads, 1.5 cm above their tips) is above the top and
        # far above where the line ended; held there, at rest.
        z_stop = arm.tcp_pose()[2, 3]
        assert 0.0 < z_stop < 0.05
        world.step(250)  # 0.5 s later it is still there: held, not pushing on
        assert arm.tcp_pose()[2, 3] == pytest.approx(z_stop, abs=1e-3)  # 1 mm: servo hold on the contact
        # Locked until unlocked: every motion command raises and nothing moves.
        q = arm.joint_positions()
        with pytest.raises(ProtectiveStopError, match="unlock"):
            arm.move_joints(q + 0.01, 0.5, 1.0)
        np.testing.assert_array_equal(arm.joint_positions(), q)
        arm.unlock_protective_stop()
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.15]), 0.1, 1.0)  # back up, free again
        assert arm.tcp_pose()[2, 3] == pytest.approx(0.15, abs=1e-3)  # 1 mm: settled servo residual


def test_without_a_limit_the_same_push_does_not_stop():
    with _world() as world, SimArm(world, protective_stop_force_n=None) as arm:
        T0 = arm.tcp_pose()
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.02]), 0.25, 1.0)
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], -0.01]), 0.1, 1.0)  # presses on the table
        assert not arm.protective_stopped
