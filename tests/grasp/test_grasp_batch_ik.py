"""Batched closed-form IK agrees with the robot layer's single-target solver."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.grasp import ik_branches_batch, ik_nearest_batch
from prompose_grasp.grasp.batch_ik import FK_REACH_TOL, branch_order, fk_reaches
from prompose_grasp.robot import load_robot
from prompose_grasp.robot.kinematics import fk_batch, ik_branches


@pytest.mark.parametrize("name", ["ur5e", "ur16e"])
def test_branches_match_the_robot_layer(name):
    robot = load_robot(name)
    rng = np.random.default_rng(3)
    T = fk_batch(robot.spec, robot.random_configurations(rng, 150))
    Q, valid = ik_branches_batch(robot.spec, T)
    for i in range(len(T)):
        ref = ik_branches(robot.spec, T[i])
        got = Q[i][valid[i]]
        assert len(got) == len(ref)
        # Same branches (both in (-pi, pi], same arithmetic up to rounding).
        np.testing.assert_allclose(np.sort(got, axis=0), np.sort(ref, axis=0), atol=1e-9)


def test_nearest_matches_ik_all_and_refuses_unreachable():
    robot = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.145])
    rng = np.random.default_rng(4)
    lower, upper = robot.joint_limits
    T = fk_batch(robot.spec, robot.random_configurations(rng, 100))
    seed = robot.random_configurations(rng, 1)[0]
    q, ok, _ = ik_nearest_batch(robot.spec, T, seed, lower, upper)
    assert ok.all()
    for i in range(len(T)):
        np.testing.assert_allclose(q[i], robot.ik_all(T[i], seed, frame="flange")[0], atol=1e-9)  # rounding
    far = T.copy()
    direction = far[:, :3, 3] / np.linalg.norm(far[:, :3, 3], axis=1, keepdims=True)
    far[:, :3, 3] = 3.0 * direction  # 3 m from the base: over three times the UR5e's 0.85 m reach
    _, ok_far, _ = ik_nearest_batch(robot.spec, far, seed, lower, upper)
    assert not ok_far.any()
    # Per-target seeds: each answer is the one nearest its own seed.
    seeds = robot.random_configurations(rng, len(T))
    q2, ok2, _ = ik_nearest_batch(robot.spec, T, seeds, lower, upper)
    assert ok2.all()
    for i in range(0, len(T), 10):
        np.testing.assert_allclose(q2[i], robot.ik_all(T[i], seeds[i], frame="flange")[0], atol=1e-9)


def test_targets_turned_about_the_flange_axis_share_their_branches_exactly():
    # Flipped jaw grasps and suction yaws are the same flange pose turned about its own z axis: the batch
    # solves one of each group and turns q6; every answer still equals the single-target solver's.
    robot = load_robot("ur10e")
    rng = np.random.default_rng(9)
    lower, upper = robot.joint_limits
    base = fk_batch(robot.spec, robot.random_configurations(rng, 40))
    turns = np.array([0.0, np.pi / 2, np.pi, 3 * np.pi / 2, 0.3])
    Rz = np.array(
        [
            [[np.cos(a), -np.sin(a), 0, 0], [np.sin(a), np.cos(a), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
            for a in turns
        ]
    )
    T = (base[:, None] @ Rz[None]).reshape(-1, 4, 4)
    seed = robot.random_configurations(rng, 1)[0]
    q, ok, _ = ik_nearest_batch(robot.spec, T, seed, lower, upper)
    assert ok.all()
    for i in range(len(T)):
        np.testing.assert_allclose(q[i], robot.ik_all(T[i], seed, frame="flange")[0], atol=1e-9)  # rounding
        np.testing.assert_allclose(robot.fk(q[i]), T[i], atol=1e-12)  # exact solutions


def test_branch_order_and_fk_reaches():
    """Every branch `branch_order` lists reaches the target by forward kinematics, the picked one first and
    none twice; a pose moved by 10 x the tolerance is not reached."""
    robot = load_robot("ur5e")
    rng = np.random.default_rng(5)
    lower, upper = robot.joint_limits
    T = fk_batch(robot.spec, robot.random_configurations(rng, 20))
    q, ok, branches = ik_nearest_batch(robot.spec, T, np.zeros(6), lower, upper)
    for i in np.flatnonzero(ok):
        order = branch_order(q[i], branches[i])
        np.testing.assert_array_equal(order[0], q[i])
        assert len(order) == 1 + sum(
            bool(np.all(np.isfinite(b)) and np.max(np.abs(b - q[i])) > 1e-9) for b in branches[i]
        )
        # The unpicked branches are unverified by `ik_nearest_batch`, but closed-form solutions of an
        # in-range pose reach it exactly (~1e-15 m).
        assert np.all(
            fk_reaches(fk_batch(robot.spec, np.array(order)), np.broadcast_to(T[i], (len(order), 4, 4)))
        )
        moved = T[i].copy()
        moved[0, 3] += 10 * FK_REACH_TOL
        assert not fk_reaches(robot.fk(q[i]), moved)
