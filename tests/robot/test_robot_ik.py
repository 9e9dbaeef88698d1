"""IK: closed-form branches, the three methods on seeded reachable targets, clean failures, support plane."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from prompose_grasp.errors import UnknownNameError
from prompose_grasp.geometry.se3 import make_T, random_rotation
from prompose_grasp.robot import IKConfig, known_robots, load_robot
from prompose_grasp.robot.kinematics import fk, ik_branches, nearest_in_limits, wrap_to_pi

# Closed-form branches are exact up to float64 rounding through ~10 trig calls and 4x4 products.
EXACT_M = 1e-9
EXACT_RAD = 1e-9
# The accuracy bar for a solved target.
TARGET_M = 1e-3
TARGET_RAD = np.deg2rad(0.1)


@pytest.mark.parametrize("name", known_robots())
def test_closed_form_recovers_the_generating_configuration(name):
    robot = load_robot(name)
    lower, upper = robot.joint_limits
    rng = np.random.default_rng(11)
    for q in robot.random_configurations(rng, 40):
        T = robot.fk(q)
        branches = ik_branches(robot.spec, T, q6_if_singular=q[5])
        assert 1 <= len(branches) <= 8
        for b in branches:  # every branch is a genuine solution
            T_b = fk(robot.spec, b)
            assert np.linalg.norm(T_b[:3, 3] - T[:3, 3]) <= EXACT_M
            assert np.abs(T_b[:3, :3] - T[:3, :3]).max() <= EXACT_RAD
        # ... and one of them is q itself, modulo whole turns; seeded with q it is chosen, unshifted.
        assert np.min(np.abs(wrap_to_pi(branches - q)).max(axis=1)) <= 1e-7  # branch check tolerance
        nearest = nearest_in_limits(branches, q, lower, upper)
        np.testing.assert_allclose(nearest[0], q, atol=1e-7)  # branch check tolerance


def test_a_generic_pose_has_eight_distinct_branches():
    # Many poses admit all 8 (2 shoulder x 2 wrist x 2 elbow); the first seeded one found is used.
    robot = load_robot("ur5e")
    rng = np.random.default_rng(17)
    branches = np.empty((0, 6))
    while len(branches) < 8:
        branches = ik_branches(robot.spec, robot.fk(robot.random_configurations(rng, 1)[0]))
    gaps = np.abs(wrap_to_pi(branches[:, None, :] - branches[None, :, :])).max(axis=2)
    assert np.all(gaps[~np.eye(8, dtype=bool)] > 1e-3)


def test_wrist_singularity_takes_q6_from_the_seed():
    robot = load_robot("ur5e")
    q = np.array([0.2, -1.0, 1.5, -0.5, 0.0, 0.4])  # q5 = 0: joints 4 and 6 aligned
    result = robot.ik(robot.fk(q), q_seed=q)
    assert result.success and result.position_error_m <= EXACT_M and result.rotation_error_rad <= EXACT_RAD
    assert result.q[5] == pytest.approx(q[5])


@pytest.mark.parametrize("name", known_robots())
def test_closed_form_ik_succeeds_on_seeded_reachable_targets(name):
    robot = load_robot(name)
    rng = np.random.default_rng(12)
    for q_true, q_seed in zip(robot.random_configurations(rng, 30), robot.random_configurations(rng, 30)):
        result = robot.ik(robot.fk(q_true), q_seed=q_seed)
        assert result.success, result.message
        assert result.position_error_m <= EXACT_M and result.rotation_error_rad <= EXACT_RAD
        lower, upper = robot.joint_limits
        assert np.all(result.q >= lower) and np.all(result.q <= upper)
        # Nearest branch: no other in-limit solution is closer to the seed.
        others = robot.ik_all(robot.fk(q_true), q_seed=q_seed)
        assert np.linalg.norm(result.q - q_seed) <= np.linalg.norm(others - q_seed, axis=1).min() + 1e-9


@pytest.mark.parametrize("method", ["mink", "pinocchio"])
def test_iterative_methods_from_closed_form_seeds(method):
    robot = load_robot("ur5e")
    rng = np.random.default_rng(13)
    for q_true, q_seed in zip(robot.random_configurations(rng, 15), robot.random_configurations(rng, 15)):
        T = robot.fk(q_true)
        result = robot.ik(T, q_seed=q_seed, method=method)
        assert result.success and result.method == method
        assert result.position_error_m <= TARGET_M and result.rotation_error_rad <= TARGET_RAD


@pytest.mark.parametrize("method", ["mink", "pinocchio"])
def test_iterative_methods_on_their_own_converge_from_a_nearby_seed(method):
    # Without closed-form seeding, a seed 0.3 rad per joint away is inside the basin: one seed must do.
    robot = load_robot("ur10e")
    config = IKConfig(closed_form_seeds=False, max_seeds=1)
    rng = np.random.default_rng(14)
    for q_true in robot.random_configurations(rng, 10):
        q_true = wrap_to_pi(q_true)
        q_true[2] = np.clip(q_true[2], -2.5, 2.5)  # keep the elbow off its +-pi limit
        q_seed = q_true + rng.uniform(-0.3, 0.3, size=6)
        result = robot.ik(robot.fk(q_true), q_seed=q_seed, method=method, config=config)
        assert result.success, result.message
        assert result.position_error_m <= config.position_tol_m
        assert result.rotation_error_rad <= config.rotation_tol_rad
        assert result.iterations >= 1


def test_mink_error_falls_along_the_solve():
    robot = load_robot("ur5e")
    q_true = np.array([0.3, -1.2, 1.3, -1.1, -1.5, 0.2])
    T = robot.fk(q_true)
    errors, results = [], []
    for iterations in (1, 2, 3, 4, 5):
        config = IKConfig(closed_form_seeds=False, max_seeds=1, max_iterations=iterations)
        results.append(robot.ik(T, q_seed=q_true + 0.2, method="mink", config=config))
        errors.append(results[-1].position_error_m + results[-1].rotation_error_rad)
    # Gauss-Newton from 0.2 rad away: the error falls every step and is within tolerance in at most 5 steps.
    converged = next(k for k, r in enumerate(results) if r.success)
    assert all(b < a for a, b in itertools.pairwise(errors[: converged + 1]))
    assert errors[converged] <= 2e-5  # position_tol_m + rotation_tol_rad of the default IKConfig


@pytest.mark.parametrize("method", ["closed_form", "mink", "pinocchio"])
def test_unreachable_targets_fail_cleanly(method):
    robot = load_robot("ur5e")
    rng = np.random.default_rng(15)
    for _ in range(3):
        direction = rng.normal(size=3)
        T = make_T(random_rotation(rng), 1.5 * robot.spec.reach_m * direction / np.linalg.norm(direction))
        seed = np.zeros(6)
        result = robot.ik(T, q_seed=seed, method=method)
        assert not result.success
        assert result.message
        assert result.position_error_m > TARGET_M  # the reported error is honest, not a claimed hit
        assert "out of reach" in result.message or method != "closed_form"


def test_tcp_frame_targets():
    robot = load_robot("ur3e", tcp_offset=[0.0, 0.03, 0.12])
    rng = np.random.default_rng(16)
    for q in robot.random_configurations(rng, 10):
        T_tcp = robot.fk_tcp(q)
        for method in ("closed_form", "pinocchio"):
            result = robot.ik(T_tcp, q_seed=q, frame="tcp", method=method)
            assert result.success
            assert np.linalg.norm(robot.fk_tcp(result.q)[:3, 3] - T_tcp[:3, 3]) <= TARGET_M
            assert result.position_error_m <= TARGET_M


def test_support_plane_excludes_branches_below_it():
    robot = load_robot("ur5e")
    config = IKConfig(support_plane_z_m=0.0, support_clearance_m=0.01)
    # Flange above the table pointing down, in front of the robot: reachable elbow-up, clear of the plane.
    T = make_T(np.diag([1.0, -1.0, -1.0]), [0.45, -0.15, 0.2])
    for method in ("closed_form", "mink"):
        result = robot.ik(T, q_seed=np.zeros(6), method=method, config=config)
        assert result.success, result.message
        assert robot.support_clearance(result.q, 0.0) >= 0.01 - 1e-6  # mink holds the bound to QP precision
    # Some branches of this target dip below the table; without the plane the nearest of all may be one.
    all_branches = robot.ik_all(T)
    assert any(robot.support_clearance(q, 0.0) < 0 for q in all_branches)
    # A flange target under the table is refused with the reason.
    T_below = make_T(np.diag([1.0, -1.0, -1.0]), [0.45, -0.15, -0.1])
    result = robot.ik(T_below, method="closed_form", config=config)
    assert not result.success and "support plane" in result.message


def test_ik_rejects_bad_arguments():
    robot = load_robot("ur5e")
    with pytest.raises(UnknownNameError, match="closed_form"):
        robot.ik(np.eye(4), method="ccd")  # type: ignore[arg-type]
    with pytest.raises(UnknownNameError, match="flange"):
        robot.ik(np.eye(4), frame="tool0")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="shape"):
        robot.ik(np.eye(3))
    with pytest.raises(ValueError, match="q_seed"):
        robot.ik(np.eye(4), q_seed=[0.0, np.nan, 0, 0, 0, 0])


def test_ik_result_is_frozen():
    result = load_robot().ik(load_robot().fk(np.full(6, 0.3)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.success = False  # type: ignore[misc]
