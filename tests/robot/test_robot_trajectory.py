"""Timed trajectories: trapezoidal profiles, synchronised joint moves and mink-tracked straight TCP lines."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnreachableError
from prompose_grasp.geometry.se3 import make_T, rotation_angle, so3_exp
from prompose_grasp.robot import load_robot
from prompose_grasp.robot.fake import HOME_Q
from prompose_grasp.robot.trajectory import joint_trajectory, linear_trajectory, trapezoid_profile
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

# Finite differences of exactly sampled profiles reproduce the caps up to float64 rounding; 1e-9 relative.
RTOL_CAP = 1e-9


def _speeds(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Finite-difference speeds of samples x(t_k) of a motion that starts from x = 0 at t = 0."""
    t = np.concatenate([[0.0], t])
    x = np.concatenate([np.zeros_like(x[:1]), x])
    return np.diff(x, axis=0) / np.diff(t).reshape(-1, *([1] * (x.ndim - 1)))


def test_trapezoid_known_duration_and_caps():
    # 1 m at 0.5 m/s and 1 m/s^2: 0.5 s ramps covering 0.125 m each, 0.75 m cruise (1.5 s): T = 2.5 s.
    t, s = trapezoid_profile(1.0, 0.5, 1.0, 0.01)
    assert t[-1] == pytest.approx(2.5, abs=1e-12)
    assert s[-1] == 1.0 and np.all(np.diff(s) >= 0)
    v = _speeds(t, s)
    assert np.max(np.abs(v)) <= 0.5 * (1 + RTOL_CAP)
    # Triangular: 0.1 m at 1 m/s and 1 m/s^2 never reaches 1 m/s; T = 2 sqrt(0.1).
    t, s = trapezoid_profile(0.1, 1.0, 1.0, 0.01)
    assert t[-1] == pytest.approx(2 * np.sqrt(0.1), abs=1e-12)
    assert t.size == 0 or np.all(np.diff(t) > 0)
    assert trapezoid_profile(0.0, 1.0, 1.0, 0.01)[0].size == 0


def test_joint_trajectory_is_a_synchronised_line_within_caps():
    q0 = HOME_Q
    q1 = HOME_Q + np.array([0.8, -0.3, 0.5, 0.0, 1.2, -2.0])
    vmax = np.array([np.pi, np.pi, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi])
    # Plan a little under the validator's 4 rad/s^2 cap: at the cap itself float64 rounding decides.
    traj = joint_trajectory(q0, q1, vmax, max_accel_rad_s2=3.9, dt_s=0.002)
    np.testing.assert_array_equal(traj.q[-1], q1)
    # Every sample lies on the joint-space segment q0 -> q1 (same fraction for all joints).
    moving = np.abs(q1 - q0) > 0
    frac = (traj.q - q0)[:, moving] / (q1 - q0)[moving]
    np.testing.assert_allclose(frac, frac[:, :1].repeat(frac.shape[1], 1), atol=1e-12)  # float64 rounding
    v = _speeds(traj.t_s, traj.q - q0)
    assert np.all(np.abs(v) <= vmax * (1 + RTOL_CAP))
    robot = load_robot("ur5e")
    CommandValidator(ValidatorConfig.for_robot(robot), fk_tcp=robot.fk_tcp).validate_trajectory(traj, q0)


def test_joint_trajectory_rejects_bad_input():
    with pytest.raises(InvalidInputError):
        joint_trajectory(np.zeros(6), np.full(6, np.nan), 1.0, 1.0)
    with pytest.raises(InvalidInputError):
        joint_trajectory(np.zeros(6), np.ones(6), 0.0, 1.0)
    held = joint_trajectory(HOME_Q, HOME_Q, 1.0, 1.0)
    assert len(held) == 1 and np.array_equal(held.q[0], HOME_Q)


@pytest.fixture(scope="module")
def ur5e_with_tcp():
    return load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.15])


def test_linear_trajectory_follows_the_line_within_speed_limits(ur5e_with_tcp):
    robot = ur5e_with_tcp
    T_start = robot.fk_tcp(HOME_Q)
    T_goal = make_T(T_start[:3, :3] @ so3_exp([0.0, 0.0, 0.3]), T_start[:3, 3] + [0.15, -0.10, -0.05])
    result = linear_trajectory(robot, HOME_Q, T_goal, speed_m_s=0.25, accel_m_s2=1.0, dt_s=0.004)
    traj = result.trajectory
    # The line is tracked to within a millimetre: mink closes each step's error up to the velocity limits.
    assert result.max_path_deviation_m < 1e-3
    T_end = robot.fk_tcp(traj.q[-1])
    assert np.linalg.norm(T_end[:3, 3] - T_goal[:3, 3]) <= 1e-4  # goal_tolerance_m default
    assert rotation_angle(T_end[:3, :3], T_goal[:3, :3]) <= 1e-3  # goal_tolerance_rad default
    # Independent check of straightness: every TCP sample lies near the segment start -> goal.
    p = np.array([robot.fk_tcp(q)[:3, 3] for q in traj.q])
    d = T_goal[:3, 3] - T_start[:3, 3]
    along = np.clip((p - T_start[:3, 3]) @ d / (d @ d), 0, 1)
    off_line = np.linalg.norm(p - (T_start[:3, 3] + along[:, None] * d), axis=1)
    assert off_line.max() < 1e-3  # same 1 mm bound as the deviation from the commanded point
    # Joint speeds within the UR5e limits, and the shared validator accepts the whole trajectory.
    v = _speeds(traj.t_s, traj.q - HOME_Q)
    assert np.all(np.abs(v) <= robot.max_joint_speed * (1 + 1e-6))  # daqp's constraint tolerance
    CommandValidator(ValidatorConfig.for_robot(robot), fk_tcp=robot.fk_tcp).validate_trajectory(traj, HOME_Q)


def test_linear_trajectory_refuses_a_goal_out_of_reach(ur5e_with_tcp):
    robot = ur5e_with_tcp
    T_start = robot.fk_tcp(HOME_Q)
    T_far = make_T(T_start[:3, :3], T_start[:3, 3] + [2.0, 0.0, 0.0])  # 2 m further than the 0.85 m reach
    with pytest.raises(UnreachableError, match="left the straight line"):
        linear_trajectory(robot, HOME_Q, T_far, speed_m_s=0.5, accel_m_s2=2.0, dt_s=0.004)
