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


def test_a_guarded_line_stops_at_the_touch_without_a_protective_stop():
    # The same line into the table as above, guarded at 40 N at the pipeline's touch speed (0.05 m/s: a
    # touch is stopped only after it happened, and at 0.1 m/s stopping on the rigid table alone presses
    # over the limit): it stops where the fingers touch the table top, and the arm stays usable.
    with _world() as world, SimArm(world) as arm:
        assert arm.senses_contact
        T0 = arm.tcp_pose()
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.15]), 0.25, 1.0)
        reached = arm.move_linear_until_contact(make_T(R_DOWN, [T0[0, 3], T0[1, 3], -0.05]), 0.05, 1.0, 40.0)
        assert reached is False and not arm.protective_stopped
        assert arm.max_external_force_n < PROTECTIVE_STOP_FORCE_N
        # The tcp sits 1.5 cm above the pads' tips, so it stops within a few millimetres of that over the
        # table top (z = 0): the arm stopped at the touch instead of pressing on to the line's end.
        assert 0.005 < arm.tcp_pose()[2, 3] < 0.03
        arm.move_linear(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.15]), 0.1, 1.0)  # backs off: not locked
        # A free line with the same guard is completed and says so.
        assert arm.move_linear_until_contact(make_T(R_DOWN, [T0[0, 3], T0[1, 3], 0.10]), 0.2, 1.0, 40.0)
        assert arm.tcp_pose()[2, 3] == pytest.approx(0.10, abs=1e-3)  # 1 mm: settled servo residual


def test_a_guard_at_or_over_the_safety_limit_is_refused():
    with _world() as world, SimArm(world) as arm:
        T = arm.tcp_pose()
        for bad in (0.0, -5.0, float("nan"), PROTECTIVE_STOP_FORCE_N, 400.0):
            with pytest.raises(InvalidInputError, match="max_force_n"):
                arm.move_linear_until_contact(T, 0.1, 1.0, bad)
