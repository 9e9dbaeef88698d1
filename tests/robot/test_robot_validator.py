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
        validator.validate_joint_move(q, 1.0, 1.0, HOME_Q)


def test_nan_target_is_refused(validator):
    q = HOME_Q.copy()
    q[4] = np.nan
    with pytest.raises(UnsafeCommandError, match=r"joint 4 \(wrist_2_joint\).*NaN"):
        validator.validate_joint_move(q, 1.0, 1.0, HOME_Q)
    with pytest.raises(InvalidInputError, match=r"q_target \[rad\] must have shape \(6,\); got \(5,\)"):
        validator.validate_joint_move(np.zeros(5), 1.0, 1.0, HOME_Q)


def test_too_fast_and_bad_speeds_are_refused(validator):
    with pytest.raises(UnsafeCommandError, match=r"joint speed 4 rad/s exceeds the cap 3\.14159"):
        validator.validate_joint_move(HOME_Q, speed=4.0, accel=1.0, q_current=HOME_Q)
    with pytest.raises(UnsafeCommandError, match="joint acceleration 50 rad/s\\^2 exceeds"):
        validator.validate_joint_move(HOME_Q, speed=1.0, accel=50.0, q_current=HOME_Q)
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(UnsafeCommandError, match="finite and > 0"):
            validator.validate_joint_move(HOME_Q, speed=bad, accel=1.0, q_current=HOME_Q)


def test_clip_speed_lowers_the_speed_instead(validator):
    clipping = CommandValidator(dataclasses.replace(validator.config, clip_speed=True))
    command = clipping.validate_joint_move(HOME_Q, speed=10.0, accel=1.0, q_current=HOME_Q)
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
        narrow.validate_joint_move(HOME_Q, 1.0, 1.0, HOME_Q)
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


E0 = np.eye(6)[0]


def test_waypoint_at_t0_must_be_the_current_position(validator):
    q1 = HOME_Q + 0.198 * E0  # within the 0.2 rad waypoint step, but reached in zero time
    with pytest.raises(UnsafeCommandError, match=r"waypoint 0 is at t = 0 but joint 0 .* is 0\.198 rad from"):
        validator.validate_trajectory(JointTrajectory(t_s=[0.0, 1.0], q=[q1, q1]), HOME_Q)
    near = HOME_Q + 0.5e-3 * E0  # within start_tolerance_rad (1e-3): the start itself
    ramp = _ramp(near, near + 0.2, duration_s=1.0, n=50)
    sent = validator.validate_trajectory(
        JointTrajectory(t_s=np.concatenate([[0.0], ramp.t_s]), q=np.vstack([near, ramp.q])), HOME_Q
    )
    assert sent.t_s[0] == 0.0
    strict = CommandValidator(dataclasses.replace(validator.config, start_tolerance_rad=1e-4))
    with pytest.raises(UnsafeCommandError, match=r"0\.0005 rad from the current position"):
        strict.validate_trajectory(sent, HOME_Q)


def test_trajectory_must_start_and_end_at_rest(validator):
    # Full speed (3.1 rad/s) from the first sample: 3.1 rad/s reached in half of 0.05 s is 124 rad/s^2.
    jump_start = JointTrajectory(t_s=[0.05, 0.1], q=[HOME_Q + 0.155 * E0, HOME_Q + 0.31 * E0])
    with pytest.raises(UnsafeCommandError, match=r"joint 0 .* would accelerate at 124 rad/s\^2"):
        validator.validate_trajectory(jump_start, HOME_Q)
    # A ramp that reaches 1 rad/s smoothly, then stops dead at its last sample: 1 rad/s lost in 5 ms.
    t = np.arange(1, 201) * 0.01
    speed = np.minimum(t, 1.0)  # 1 rad/s^2 up to 1 rad/s, then constant
    q = HOME_Q + np.cumsum(speed * 0.01)[:, None] * E0
    with pytest.raises(UnsafeCommandError, match=r"accelerate at 2\d\d rad/s\^2 coming to rest"):
        validator.validate_trajectory(JointTrajectory(t_s=t, q=q), HOME_Q)


def test_rest_to_rest_profiles_within_the_cap_pass_however_sampled(validator):
    from prompose_grasp.robot.trajectory import joint_trajectory

    cap = validator.config.max_joint_accel_rad_s2
    for dt in (0.002, 0.0137, 0.1):
        traj = joint_trajectory(HOME_Q, HOME_Q + np.array([1.0, -0.5, 0.3, 0, 0, 0.8]), 2.0, cap, dt_s=dt)
        validator.validate_trajectory(traj, HOME_Q)


def test_mutated_trajectory_with_a_zero_length_segment_is_refused(validator):
    traj = _ramp(HOME_Q, HOME_Q + 0.5, duration_s=2.0, n=100)
    traj.t_s[10] = traj.t_s[9]  # the arrays stay writable; the validator checks them again
    with pytest.raises(InvalidInputError, match=r"strictly increasing.*waypoints 9 and 10 .* rad apart"):
        validator.validate_trajectory(traj, HOME_Q)


def test_joint_move_workspace_is_checked_along_the_line(validator):
    # The base turns from -1.5 to +1.5 rad: the TCP swings through x = -0.49 m on the way, while both ends
    # are at x > -0.17 m.
    q_from, q_to = HOME_Q - 1.5 * E0, HOME_Q + 1.5 * E0
    x_ends = min(ROBOT.fk_tcp(q_from)[0, 3], ROBOT.fk_tcp(q_to)[0, 3])
    x_mid = ROBOT.fk_tcp(HOME_Q)[0, 3]
    assert x_ends - x_mid > 0.3
    lo = np.array(validator.config.workspace_min_m)
    lo[0] = 0.5 * (x_ends + x_mid)
    boxed = CommandValidator(
        dataclasses.replace(validator.config, workspace_min_m=lo, max_waypoint_step_rad=np.pi),
        fk_tcp=ROBOT.fk_tcp,
    )
    boxed.validate_configuration(q_to, q_from)  # the target alone is inside
    with pytest.raises(UnsafeCommandError, match=r"% of the way\): TCP x = .* outside the workspace"):
        boxed.validate_joint_move(q_to, 1.0, 1.0, q_current=q_from)
    with pytest.raises(UnsafeCommandError, match=r"waypoint 0 \(.*% of the way\): TCP x"):  # one segment
        boxed.validate_trajectory(JointTrajectory(t_s=[10.0], q=[q_to]), q_from)


@pytest.mark.parametrize(
    "bad",
    [None, "0.5", ["0.5"] * 6, [True] * 6, [1.0, 2.0, True, 0, 0, 0], np.zeros(6, dtype=bool),
     np.zeros(6, dtype=complex), np.array(0.5), {"q": 1}, np.zeros((1, 6)), np.zeros(6, dtype=object),
     [[0.0] * 3, [0.0] * 2]],
)  # fmt: skip
def test_malformed_joint_vectors_are_invalid_input(validator, bad):
    with pytest.raises(InvalidInputError, match=r"\(6,\) real numbers|shape \(6,\)"):
        validator.validate_joint_move(bad, 1.0, 1.0, HOME_Q)
    with pytest.raises(InvalidInputError, match="q_current"):
        validator.validate_joint_move(HOME_Q, 1.0, 1.0, bad)
    with pytest.raises(InvalidInputError, match="q_current"):
        validator.validate_trajectory(_ramp(HOME_Q, HOME_Q + 0.1, 1.0, 10), bad)


@pytest.mark.parametrize(
    "bad", ["fast", None, [1.0], {}, np.array(1.0), np.array([1.0]), True, np.True_, 1 + 0j, 10**400]
)
def test_malformed_speeds_are_invalid_input_naming_what_is_accepted(validator, bad):
    with pytest.raises(InvalidInputError, match="must be a real number"):
        validator.validate_joint_move(HOME_Q, bad, 1.0, HOME_Q)
    with pytest.raises(InvalidInputError, match="must be a real number"):
        validator.validate_joint_move(HOME_Q, 1.0, bad, HOME_Q)
    T = ROBOT.fk_tcp(HOME_Q)
    with pytest.raises(InvalidInputError, match=r"TCP speed .* must be a real number"):
        validator.validate_linear_move(T, bad, 1.0)
    with pytest.raises(InvalidInputError, match=r"TCP acceleration .* must be a real number"):
        validator.validate_linear_move(T, 0.1, bad)


def test_integer_arguments_are_accepted_and_converted_exactly(validator):
    q_int = [0, -1, 1, -1, -1, 0]
    command = validator.validate_joint_move(q_int, 1, 2, np.array(q_int, dtype=np.int32))
    assert command.q.dtype == np.float64 and command.q.tolist() == q_int
    assert (command.speed_rad_s, command.accel_rad_s2) == (1.0, 2.0)
    command = validator.validate_joint_move(
        np.float32(0.5) + np.zeros(6, np.float32), np.float32(0.5), 1, q_int
    )
    assert command.q.dtype == np.float64 and command.speed_rad_s == 0.5


def test_malformed_poses_and_trajectories_are_invalid_input(validator):
    T = ROBOT.fk_tcp(HOME_Q)
    for bad in (None, "T", T[:3], T.astype(complex), T.astype(bool), T.tolist()[:3], np.array(1.0)):
        with pytest.raises(InvalidInputError, match="T_base_tcp"):
            validator.validate_linear_move(bad, 0.1, 1.0)
    assert validator.validate_linear_move(T.tolist(), 0.1, 1).T_base_tcp.dtype == np.float64
    for bad in (None, "trajectory", {"t_s": [1.0], "q": [HOME_Q]}, (np.array([1.0]), HOME_Q[None])):
        with pytest.raises(InvalidInputError, match="expected a JointTrajectory"):
            validator.validate_trajectory(bad, HOME_Q)
    with pytest.raises(InvalidInputError, match=r"JointTrajectory\.t_s"):
        JointTrajectory(t_s=["0.5"], q=[HOME_Q])
    with pytest.raises(InvalidInputError, match=r"JointTrajectory\.q"):
        JointTrajectory(t_s=[0.5], q=[HOME_Q.astype(complex)])


def test_config_checks_its_new_fields():
    with pytest.raises(InvalidInputError, match="start_tolerance_rad must not exceed"):
        ValidatorConfig.for_robot(ROBOT, start_tolerance_rad=0.3)
    with pytest.raises(InvalidInputError, match="workspace_step_rad"):
        ValidatorConfig.for_robot(ROBOT, workspace_step_rad=0.0)
    with pytest.raises(InvalidInputError, match="clip_speed must be a bool"):
        ValidatorConfig.for_robot(ROBOT, clip_speed="yes")
    with pytest.raises(InvalidInputError, match="max_joint_accel_rad_s2 must be a real number"):
        ValidatorConfig.for_robot(ROBOT, max_joint_accel_rad_s2="4")
    assert ValidatorConfig.for_robot(ROBOT, start_tolerance_rad=0).start_tolerance_rad == 0.0
