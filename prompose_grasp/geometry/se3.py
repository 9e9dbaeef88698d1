"""Rigid transforms as 4x4 homogeneous matrices, with SO(3)/SE(3) exp and log.

Naming: `T_a_b` maps points from frame b to frame a (`x_a = T_a_b @ x_b`), so chains read
`T_base_obj = T_base_cam @ T_cam_obj`. Twists are `xi = (v, omega)`, translation part first, as in mink.
Quaternions are scalar-first and say so (`quat_wxyz`). scipy's `Rotation` does the SO(3) heavy lifting.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.tolerances import ROTATION_ATOL, SMALL_ANGLE_RAD


def _array(x: ArrayLike, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a numeric array of shape {shape}, got {x!r:.80}") from None
    if a.shape != shape:
        raise InvalidInputError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} must be finite, got NaN or inf")
    return a


def as_rotation(R: ArrayLike, name: str = "R", atol: float = ROTATION_ATOL) -> np.ndarray:
    """Validate a rotation matrix: (3, 3), finite, orthonormal, det +1. Returns a float64 copy."""
    R = _array(R, (3, 3), name)
    # max |R^T R - I| is the orthonormality test; cheaper than np.allclose on the hot path of box IoU.
    if float(np.abs(R.T @ R - np.eye(3)).max()) > atol or abs(np.linalg.det(R) - 1.0) > atol:
        raise InvalidInputError(
            f"{name} is not a rotation matrix (needs R^T R = I and det R = +1 within {atol}); "
            f"det = {np.linalg.det(R):.6g}"
        )
    return R.copy()


def as_transform(T: ArrayLike, name: str = "T") -> np.ndarray:
    """Validate a rigid transform: (4, 4), rotation block, last row (0, 0, 0, 1). Returns a float64 copy."""
    T = _array(T, (4, 4), name)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=ROTATION_ATOL):
        raise InvalidInputError(f"{name} must have last row (0, 0, 0, 1), got {T[3]}")
    as_rotation(T[:3, :3], name=f"{name}[:3, :3]")
    return T.copy()


def project_to_so3(M: ArrayLike) -> np.ndarray:
    """The rotation nearest to a 3x3 matrix in the Frobenius norm (SVD, with the det sign fixed)."""
    U, _, Vt = np.linalg.svd(_array(M, (3, 3), "M"))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def make_T(R: ArrayLike, t: ArrayLike) -> np.ndarray:
    """(4, 4) transform from a rotation (3, 3) and a translation (3,) [m]."""
    T = np.eye(4)
    T[:3, :3] = _array(R, (3, 3), "R")
    T[:3, 3] = _array(t, (3,), "t")
    return T


def invert_T(T: ArrayLike) -> np.ndarray:
    """Inverse of a rigid transform, using R^T rather than a general matrix inverse."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def transform_points(T_a_b: ArrayLike, points_b: ArrayLike) -> np.ndarray:
    """Map (N, 3) points from frame b to frame a. Returns (N, 3) float64."""
    T_a_b = np.asarray(T_a_b, dtype=np.float64)
    P = np.asarray(points_b, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points must have shape (N, 3), got {P.shape}")
    return P @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def hat(omega: ArrayLike) -> np.ndarray:
    """The skew matrix [omega]x with [omega]x v = omega x v."""
    wx, wy, wz = np.asarray(omega, dtype=np.float64)
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


def so3_exp(omega: ArrayLike) -> np.ndarray:
    """Rotation matrix of a rotation vector (3,) [rad] (axis times angle)."""
    return Rotation.from_rotvec(_array(omega, (3,), "omega")).as_matrix()


def so3_log(R: ArrayLike) -> np.ndarray:
    """Rotation vector (3,) [rad] of a rotation matrix; the angle lies in [0, pi]."""
    return Rotation.from_matrix(as_rotation(R)).as_rotvec()


def _left_jacobian_terms(theta: float) -> tuple[float, float]:
    """Coefficients (a, b) of V = I + a W + b W^2 for W = [omega]x, theta = |omega|."""
    if theta < SMALL_ANGLE_RAD:
        return 0.5 - theta**2 / 24.0, 1.0 / 6.0 - theta**2 / 120.0
    return (1.0 - np.cos(theta)) / theta**2, (theta - np.sin(theta)) / theta**3


def se3_exp(xi: ArrayLike) -> np.ndarray:
    """Transform (4, 4) of a twist xi = (v [m], omega [rad]) (6,)."""
    xi = _array(xi, (6,), "xi")
    v, omega = xi[:3], xi[3:]
    W = hat(omega)
    a, b = _left_jacobian_terms(float(np.linalg.norm(omega)))
    V = np.eye(3) + a * W + b * W @ W
    return make_T(so3_exp(omega), V @ v)


def se3_log(T: ArrayLike) -> np.ndarray:
    """Twist xi = (v [m], omega [rad]) (6,) of a rigid transform; inverse of `se3_exp`."""
    T = as_transform(T)
    omega = so3_log(T[:3, :3])
    theta = float(np.linalg.norm(omega))
    W = hat(omega)
    if theta < SMALL_ANGLE_RAD:
        c = 1.0 / 12.0 + theta**2 / 720.0
    else:
        c = (1.0 - theta * np.sin(theta) / (2.0 * (1.0 - np.cos(theta)))) / theta**2
    V_inv = np.eye(3) - 0.5 * W + c * W @ W
    return np.concatenate([V_inv @ T[:3, 3], omega])


def rotation_angle(R_a: ArrayLike, R_b: ArrayLike) -> float:
    """Geodesic angle [rad] between two rotations, in [0, pi]: |log(R_a^T R_b)|."""
    R_rel = np.asarray(R_a, dtype=np.float64).T @ np.asarray(R_b, dtype=np.float64)
    # arccos of the trace loses precision near 0; the rotation-vector norm does not.
    return float(np.linalg.norm(Rotation.from_matrix(R_rel).as_rotvec()))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly from SO(3) (Haar measure)."""
    return Rotation.random(random_state=rng).as_matrix()


def random_transform(rng: np.random.Generator, translation_scale_m: float = 1.0) -> np.ndarray:
    """A transform with a uniform random rotation and a Gaussian translation of the given scale [m]."""
    return make_T(random_rotation(rng), rng.normal(scale=translation_scale_m, size=3))


def quat_wxyz_from_R(R: ArrayLike) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix, with w >= 0."""
    x, y, z, w = Rotation.from_matrix(as_rotation(R)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def R_from_quat_wxyz(quat_wxyz: ArrayLike) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z); it is normalised first."""
    w, x, y, z = _array(quat_wxyz, (4,), "quat_wxyz")
    if np.hypot(np.hypot(w, x), np.hypot(y, z)) < 1e-12:
        raise InvalidInputError("quat_wxyz must be non-zero")
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def T_from_pose_vector(pose: ArrayLike) -> np.ndarray:
    """(4, 4) transform from a UR pose vector (x, y, z [m], rx, ry, rz [rad], a rotation vector)."""
    p = _array(pose, (6,), "pose")
    return make_T(so3_exp(p[3:]), p[:3])


def pose_vector_from_T(T: ArrayLike) -> np.ndarray:
    """UR pose vector (x, y, z [m], rx, ry, rz [rad]) of a transform; inverse of `T_from_pose_vector`."""
    T = as_transform(T)
    return np.concatenate([T[:3, 3], so3_log(T[:3, :3])])
