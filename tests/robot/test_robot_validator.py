"""The shared command validator: what it refuses (with which message) and what it sends."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnsafeCommandError
from prompose_grasp.robot import HOME_Q, CommandValidator, JointTrajectory, ValidatorConfig, load_robot

ROBOT = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.15])


@pytest.fixture
def validator() -> CommandValidator:
    return CommandValidator(ValidatorConfig.for_robot(ROBOT), fk_tcp=ROBOT.fk_tcp)


def test_valid_joint_move_is_sent_unchanged(validator):
    q = HOME_Q + 0.1
    command = validator.validate_joint_move(q, speed=1.0, accel=2.0, q_current=HOME_Q)
    np.testing.assert_array_equal(command.q, q)
    assert (command.speed_rad_s, command.accel_rad_s2) == (1.0, 2.0)
    q[0] = 99.0  # the command holds its own copy
    assert command.q[0] != 99.0


def test_out_of_limit_target_names_joint_limit_and_value(validator):
    q = HOME_Q.copy()
    q[2] = 3.5  # elbow beyond +-pi
    with pytest.raises(
        UnsafeCommandError, match=r"joint 2 \(elbow_joint\) target 3\.5 rad is outside.*3\.14159"
    ):
        validator.validate_joint_move(q, 1.0, 1.0)


def test_nan_target_is_refused(validator):
    q = HOME_Q.copy()
    q[4] = np.nan
    with pytest.raises(UnsafeCommandError, match=r"joint 4 \(wrist_2_joint\).*NaN"):
        validator.validate_joint_move(q, 1.0, 1.0)
    with pytest.raises(UnsafeCommandError, match="shape"):
        validator.validate_joint_move(np.zeros(5), 1.0, 1.0)


def test_too_fast_and_bad_speeds_are_refused(validator):
    with pytest.raises(UnsafeCommandError, match=r"joint speed 4 rad/s exceeds the cap 3\.14159"):
        validator.validate_joint_move(HOME_Q, speed=4.0, accel=1.0)
    with pytest.raises(UnsafeCommandError, match="joint acceleration 50 rad/s\\^2 exceeds"):
        validator.validate_joint_move(HOME_Q, speed=1.0, accel=50.0)
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(UnsafeCommandError, match="finite and > 0"):
            validator.validate_joint_move(HOME_Q, speed=bad, accel=1.0)


def test_clip_speed_lowers_the_speed_instead(validator):
    clipping = CommandValidator(dataclasses.replace(validator.config, clip_speed=True))
    command = clipping.validate_joint_move(HOME_Q, speed=10.0, accel=1.0)
    assert command.speed_rad_s == pytest.approx(np.pi)


def test_too_large_step_is_refused(validator):
    q = HOME_Q.copy()
    q[5] += 2 * np.pi  # same pose, wrist spun a full turn: the classic wrong IK representative
    with pytest.raises(
        UnsafeCommandError, match=r"joint 5 \(wrist_3_joint\) would move 6\.28.*limit is 3\.14"
    ):
        validator.validate_joint_move(q, 1.0, 1.0, q_current=HOME_Q)


def test_workspace_box(validator):
    narrow = CommandValidator(
        dataclasses.replace(validator.config, workspace_min_m=(-1, -1, 0.5), workspace_max_m=(1, 1, 1)),
        fk_tcp=ROBOT.fk_tcp,
    )
    z_tcp = ROBOT.fk_tcp(HOME_Q)[2, 3]
    assert z_tcp < 0.5
    with pytest.raises(UnsafeCommandError, match=r"TCP z = .* outside the workspace"):
        narrow.validate_joint_move(HOME_Q, 1.0, 1.0)
    T = ROBOT.fk_tcp(HOME_Q)
    with pytest.raises(UnsafeCommandError, match="TCP z"):
        narrow.validate_linear_move(T, 0.1, 0.5)


def test_linear_move_checks(validator):
    T = ROBOT.fk_tcp(HOME_Q)
    command = validator.validate_linear_move(T, 0.2, 1.0)
    np.testing.assert_array_equal(command.T_base_tcp, T)
    with pytest.raises(UnsafeCommandError, match="TCP speed 2 m/s exceeds"):
        validator.validate_linear_move(T, 2.0, 1.0)
    bad = T.copy()
    bad[0, 3] = np.nan
    with pytest.raises(UnsafeCommandError, match="finite"):
        validator.validate_linear_move(bad, 0.1, 1.0)
    sheared = T.copy()
    sheared[:3, :3] *= 1.1
    with pytest.raises(UnsafeCommandError, match="rigid"):
        validator.validate_linear_move(sheared, 0.1, 1.0)


def _ramp(q_from: np.ndarray, q_to: np.ndarray, duration_s: float, n: int) -> JointTrajectory:
    s = np.linspace(0.0, 1.0, n + 1)[1:]
    smooth = 3 * s**2 - 2 * s**3  # zero speed at both ends
    return JointTrajectory(t_s=duration_s * s, q=q_from + smooth[:, None] * (q_to - q_from))


def test_smooth_trajectory_is_accepted(validator):
    trajectory = _ramp(HOME_Q, HOME_Q + 0.5, duration_s=2.0, n=100)
    sent = validator.validate_trajectory(trajectory, HOME_Q)
    np.testing.assert_array_equal(sent.q, trajectory.q)


def test_trajectory_too_fast_too_jerky_or_jumping_is_refused(validator):
    with pytest.raises(UnsafeCommandError, match=r"rad/s before waypoint .* speed limit is 3\.14"):
        validator.validate_trajectory(_ramp(HOME_Q, HOME_Q + 1.0, duration_s=0.3, n=20), HOME_Q)
    with pytest.raises(UnsafeCommandError, match=r"accelerate at .* rad/s\^2"):
        validator.validate_trajectory(_ramp(HOME_Q, HOME_Q + 0.5, duration_s=0.6, n=100), HOME_Q)
    with pytest.raises(UnsafeCommandError, match=r"waypoint 0: joint 0 .* would move 0\.5 rad in one step"):
        validator.validate_trajectory(
            JointTrajectory(t_s=[1.0], q=[HOME_Q + np.array([0.5, 0, 0, 0, 0, 0])]), HOME_Q
        )
    out_of_limits = _ramp(HOME_Q, HOME_Q + 0.5, duration_s=2.0, n=100)
    out_of_limits.q[50, 2] = 4.0
    with pytest.raises(UnsafeCommandError, match=r"waypoint 50: joint 2 \(elbow_joint\)"):
        validator.validate_trajectory(out_of_limits, HOME_Q)


def test_trajectory_and_config_validate_their_own_fields():
    with pytest.raises(InvalidInputError, match="strictly increasing"):
        JointTrajectory(t_s=[0.1, 0.1], q=np.zeros((2, 6)))
    with pytest.raises(InvalidInputError, match=r"\(N, 6\)"):
        JointTrajectory(t_s=[0.1], q=np.zeros((1, 5)))
    with pytest.raises(InvalidInputError, match="max_waypoint_step_rad"):
        ValidatorConfig.for_robot(ROBOT, max_waypoint_step_rad=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ValidatorConfig.for_robot(ROBOT).clip_speed = True  # type: ignore[misc]
