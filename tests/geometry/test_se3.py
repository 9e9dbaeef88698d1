"""SE(3) helpers: Lie-group axioms and round trips on seeded random samples."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import se3

# float64 products and scipy's rotvec conversions of a few matrices stay within ~1e-14; 1e-12 leaves headroom.
ATOL = 1e-12
N_SAMPLES = 50


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


def test_random_rotations_are_rotations(rng):
    for _ in range(N_SAMPLES):
        R = se3.random_rotation(rng)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=ATOL)


def test_so3_exp_log_round_trip(rng):
    for _ in range(N_SAMPLES):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0.0, np.pi - 1e-3)  # below pi, where log is unique
        omega = angle * axis
        np.testing.assert_allclose(se3.so3_log(se3.so3_exp(omega)), omega, atol=ATOL)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-8, 1e-6, 1e-4])
def test_so3_exp_log_near_zero(angle):
    omega = angle * np.array([0.6, -0.8, 0.0])
    np.testing.assert_allclose(se3.so3_log(se3.so3_exp(omega)), omega, atol=ATOL)
    # Against the first-order expansion exp(W) = I + W, exact up to O(angle^2).
    np.testing.assert_allclose(se3.so3_exp(omega), np.eye(3) + se3.hat(omega), atol=angle**2 + ATOL)


@pytest.mark.parametrize("delta", [0.0, 1e-9, 1e-6])
def test_so3_log_near_pi(delta):
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    R = se3.so3_exp((np.pi - delta) * axis)
    omega = se3.so3_log(R)
    # At exactly pi the sign of the axis is arbitrary; the rotation is what must round-trip.
    # Near pi the log's axis is ill-conditioned (~eps / delta); 1e-7 bounds it for these angles.
    np.testing.assert_allclose(se3.so3_exp(omega), R, atol=1e-7)
    assert np.linalg.norm(omega) == pytest.approx(np.pi - delta, abs=1e-7)


def test_se3_exp_log_round_trip(rng):
    for _ in range(N_SAMPLES):
        T = se3.random_transform(rng)
        np.testing.assert_allclose(se3.se3_exp(se3.se3_log(T)), T, atol=1e-10)  # log near pi amplifies eps


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-7, 1e-5])
def test_se3_exp_log_near_zero(angle):
    xi = np.array([0.1, -0.2, 0.3, angle, -angle, 0.5 * angle])
    np.testing.assert_allclose(se3.se3_log(se3.se3_exp(xi)), xi, atol=ATOL)


def test_se3_exp_pure_translation_and_rotation():
    np.testing.assert_allclose(se3.se3_exp([1.0, 2.0, 3.0, 0, 0, 0]), se3.make_T(np.eye(3), [1, 2, 3]))
    T = se3.se3_exp([0, 0, 0, 0, 0, np.pi / 2])
    np.testing.assert_allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=ATOL)
    np.testing.assert_allclose(T[:3, 3], 0.0, atol=ATOL)


def test_inverse_and_identity(rng):
    for _ in range(N_SAMPLES):
        T = se3.random_transform(rng)
        np.testing.assert_allclose(T @ se3.invert_T(T), np.eye(4), atol=ATOL)
        np.testing.assert_allclose(se3.invert_T(T), np.linalg.inv(T), atol=ATOL)


def test_composition_associative_and_matches_point_maps(rng):
    for _ in range(N_SAMPLES):
        T_a_b, T_b_c, T_c_d = (se3.random_transform(rng) for _ in range(3))
        np.testing.assert_allclose((T_a_b @ T_b_c) @ T_c_d, T_a_b @ (T_b_c @ T_c_d), atol=ATOL)
        p_c = rng.normal(size=(5, 3))
        np.testing.assert_allclose(
            se3.transform_points(T_a_b @ T_b_c, p_c),
            se3.transform_points(T_a_b, se3.transform_points(T_b_c, p_c)),
            atol=ATOL,
        )


def test_quaternion_round_trip_and_sign(rng):
    for _ in range(N_SAMPLES):
        R = se3.random_rotation(rng)
        q = se3.quat_wxyz_from_R(R)
        assert q[0] >= 0.0
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=ATOL)
        np.testing.assert_allclose(se3.R_from_quat_wxyz(q), R, atol=ATOL)
        np.testing.assert_allclose(se3.R_from_quat_wxyz(-q), R, atol=ATOL)  # q and -q are one rotation
        np.testing.assert_allclose(se3.R_from_quat_wxyz(3.0 * q), R, atol=ATOL)  # normalised first


def test_quaternion_known_value():
    # 90 deg about z: w = cos 45, z = sin 45.
    c = np.sqrt(0.5)
    q = se3.quat_wxyz_from_R([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(q, [c, 0, 0, c], atol=ATOL)


def test_ur_pose_vector_round_trip(rng):
    for _ in range(N_SAMPLES):
        T = se3.random_transform(rng)
        pose = se3.pose_vector_from_T(T)
        assert np.linalg.norm(pose[3:]) <= np.pi + ATOL
        np.testing.assert_allclose(se3.T_from_pose_vector(pose), T, atol=ATOL)


def test_project_to_so3(rng):
    for _ in range(N_SAMPLES):
        R = se3.random_rotation(rng)
        np.testing.assert_allclose(se3.project_to_so3(R), R, atol=ATOL)  # idempotent on rotations
        noisy = R + rng.normal(scale=1e-3, size=(3, 3))
        P = se3.project_to_so3(noisy)
        np.testing.assert_allclose(P.T @ P, np.eye(3), atol=ATOL)
        assert np.linalg.det(P) == pytest.approx(1.0, abs=ATOL)
        # The nearest rotation is at least as close as the true one (Frobenius optimality).
        assert np.linalg.norm(P - noisy) <= np.linalg.norm(R - noisy) + ATOL
    # A reflection projects to a proper rotation, not to itself.
    P = se3.project_to_so3(np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(P) == pytest.approx(1.0, abs=ATOL)


def test_rotation_angle(rng):
    for _ in range(N_SAMPLES):
        R = se3.random_rotation(rng)
        angle = rng.uniform(0.0, np.pi)
        axis = rng.normal(size=3)
        R2 = R @ se3.so3_exp(angle * axis / np.linalg.norm(axis))
        assert se3.rotation_angle(R, R2) == pytest.approx(angle, abs=1e-9)  # arccos-free, but near pi ~1e-9
    assert se3.rotation_angle(np.eye(3), np.eye(3)) == 0.0


def test_validation_errors():
    with pytest.raises(InvalidInputError, match="rotation"):
        se3.as_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InvalidInputError, match="shape"):
        se3.as_rotation(np.eye(4))
    with pytest.raises(InvalidInputError, match="finite"):
        se3.as_rotation(np.full((3, 3), np.nan))
    with pytest.raises(InvalidInputError, match="last row"):
        se3.as_transform(np.ones((4, 4)))
    with pytest.raises(InvalidInputError, match="non-zero"):
        se3.R_from_quat_wxyz([0, 0, 0, 0])
    with pytest.raises(InvalidInputError, match=r"\(N, 3\)"):
        se3.transform_points(np.eye(4), np.zeros(3))
