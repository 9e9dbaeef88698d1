"""Closed-form kinematics of the UR arms: DH forward kinematics and the analytic inverse (up to 8 branches).

Everything is numpy on (4, 4) float64 transforms in the DH convention of `ur_models` (frame 0 = `base`,
frame 6 = `flange`). The inverse is derived from the structure every UR shares: joints 2, 3 and 4 are
parallel, so the wrist-2 centre lies on a plane at distance d4 from the base axis (gives q1, two branches),
the tool z axis fixes q5 up to sign (two branches), the tool x/y axes give q6, and a planar 2R problem gives
q3 up to sign (two branches), then q2 and q4. Each branch is checked by forward kinematics before it is
returned.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import as_transform
from prompose_grasp.robot.ur_models import URSpec

#: Closed-form arguments of arcsin/arccos that overshoot [-1, 1] by less than this (rounding on targets at the
#: edge of the workspace) are clipped; a larger overshoot means the target is out of reach for that branch.
_ARG_SLACK = 1e-9

#: Below this |sin q5| [-] the wrist is singular (joints 4 and 6 aligned); q6 is free and taken from the seed.
_WRIST_SINGULAR_SIN = 1e-10

#: A closed-form branch is kept only when its forward kinematics reproduces the target to this [m] / [rad].
#: Exact branches land at ~1e-15; the slack admits targets right at the workspace boundary.
BRANCH_POSITION_TOL_M = 1e-7
BRANCH_ROTATION_TOL_RAD = 1e-7

_TWO_PI = 2.0 * math.pi


def dh_transform(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """(4, 4) transform Rz(theta) Tz(d) Tx(a) Rx(alpha) from frame i-1 to frame i (standard DH)."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _joint_vector(q: ArrayLike, name: str = "q") -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (6,):
        raise InvalidInputError(f"{name} must have shape (6,) [rad], got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InvalidInputError(f"{name} must be finite, got {q}")
    return q


def fk_frames(spec: URSpec, q: ArrayLike) -> np.ndarray:
    """(7, 4, 4) poses T_base_frame_i of DH frames 0..6 (frame 0 = base, frame 6 = flange) at q (6,) [rad]."""
    q = _joint_vector(q)
    frames = np.empty((7, 4, 4))
    frames[0] = np.eye(4)
    for i in range(6):
        frames[i + 1] = frames[i] @ dh_transform(q[i], spec.d_m[i], spec.a_m[i], spec.alpha_rad[i])
    return frames


def fk(spec: URSpec, q: ArrayLike) -> np.ndarray:
    """(4, 4) T_base_flange at q (6,) [rad]: the UR controller's TCP pose with a zero TCP offset."""
    q = _joint_vector(q)
    T = dh_transform(q[0], spec.d_m[0], spec.a_m[0], spec.alpha_rad[0])
    for i in range(1, 6):
        T = T @ dh_transform(q[i], spec.d_m[i], spec.a_m[i], spec.alpha_rad[i])
    return T


def dh_transforms(theta: np.ndarray, d: float, a: float, alpha: float) -> np.ndarray:
    """(N, 4, 4) stack of `dh_transform` for N joint angles `theta` (N,) [rad]."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    out = np.zeros((theta.shape[0], 4, 4))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2], out[:, 0, 3] = ct, -st * ca, st * sa, a * ct
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2], out[:, 1, 3] = st, ct * ca, -ct * sa, a * st
    out[:, 2, 1], out[:, 2, 2], out[:, 2, 3] = sa, ca, d
    out[:, 3, 3] = 1.0
    return out


def fk_batch(spec: URSpec, Q: ArrayLike) -> np.ndarray:
    """(N, 4, 4) T_base_flange for N configurations Q (N, 6) [rad]."""
    Q = np.asarray(Q, dtype=np.float64)
    if Q.ndim != 2 or Q.shape[1] != 6:
        raise InvalidInputError(f"Q must have shape (N, 6) [rad], got {Q.shape}")
    T = dh_transforms(Q[:, 0], spec.d_m[0], spec.a_m[0], spec.alpha_rad[0])
    for i in range(1, 6):
        T = T @ dh_transforms(Q[:, i], spec.d_m[i], spec.a_m[i], spec.alpha_rad[i])
    return T


def rotation_distance(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Geodesic angle(s) [rad] between rotations (..., 3, 3), from the chord |R_a - R_b|_F.

    The chord is 2 sqrt(2) sin(theta / 2).

    Unlike arccos of the trace, this stays accurate for tiny angles, and it needs no scipy call (hot path).
    """
    chord = np.linalg.norm(np.asarray(R_a) - np.asarray(R_b), axis=(-2, -1))
    return 2.0 * np.arcsin(np.minimum(chord / (2.0 * math.sqrt(2.0)), 1.0))


def _dh_inverse(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    T = dh_transform(theta, d, a, alpha)
    R = T[:3, :3].T
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = -R @ T[:3, 3]
    return out


def wrap_to_pi(angles: ArrayLike) -> np.ndarray:
    """Angles mapped to (-pi, pi] [rad]."""
    a = np.asarray(angles, dtype=np.float64)
    wrapped = np.mod(a + np.pi, _TWO_PI) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def _clipped(x: float) -> float | None:
    """x clipped to [-1, 1] when it overshoots by at most `_ARG_SLACK`, else None (no real angle)."""
    if x > 1.0:
        return 1.0 if x <= 1.0 + _ARG_SLACK else None
    if x < -1.0:
        return -1.0 if x >= -1.0 - _ARG_SLACK else None
    return x


def ik_branches(spec: URSpec, T_base_flange: ArrayLike, q6_if_singular: float = 0.0) -> np.ndarray:
    """All closed-form solutions for a flange pose: (K, 6) float64 [rad], K in 0..8, angles in (-pi, pi].

    Branch order: shoulder (q1) x wrist (sign of q5) x elbow (sign of q3). Branches whose forward kinematics
    miss the target by more than `BRANCH_POSITION_TOL_M` / `BRANCH_ROTATION_TOL_RAD` are dropped, so K = 0
    means the pose is out of reach. At a wrist singularity (sin q5 = 0) q6 is free and set to
    `q6_if_singular`. Joint limits are not applied here (see `nearest_in_limits`).
    """
    T = as_transform(T_base_flange, "T_base_flange")
    d1, a2, a3, d4, d5, d6 = spec.d1, spec.a2, spec.a3, spec.d4, spec.d5, spec.d6
    x6, y6, z6, p6 = T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3]
    p5 = p6 - d6 * z6

    solutions: list[list[float]] = []
    r = math.hypot(p5[0], p5[1])
    if r < 1e-12:
        return np.empty((0, 6))
    s = _clipped(d4 / r)
    if s is None:
        return np.empty((0, 6))
    phi = math.atan2(p5[1], p5[0])
    asin_s = math.asin(s)
    for q1 in (phi + asin_s, phi + math.pi - asin_s):
        s1, c1 = math.sin(q1), math.cos(q1)
        # n is the common direction of the parallel joint axes 2, 3, 4 (z1 in base coordinates).
        n = np.array([s1, -c1, 0.0])
        c5 = _clipped((float(p6 @ n) - d4) / d6)
        if c5 is None:
            continue
        acos_c5 = math.acos(c5)
        T01_inv = _dh_inverse(q1, d1, 0.0, spec.alpha_rad[0])
        for q5 in (acos_c5, -acos_c5):
            s5 = math.sin(q5)
            if abs(s5) < _WRIST_SINGULAR_SIN:
                q6 = q6_if_singular
            else:
                sign = 1.0 if s5 > 0 else -1.0
                q6 = math.atan2(-sign * float(y6 @ n), sign * float(x6 @ n))
            T45_inv = _dh_inverse(q5, d5, 0.0, spec.alpha_rad[4])
            T56_inv = _dh_inverse(q6, d6, 0.0, spec.alpha_rad[5])
            T14 = T01_inv @ T @ T56_inv @ T45_inv
            # Frame 3's origin sits d4 back along z3 = y4 from frame 4's origin.
            p13 = T14[:3, :3] @ np.array([0.0, -d4, 0.0]) + T14[:3, 3]
            c3 = _clipped((p13[0] ** 2 + p13[1] ** 2 - a2**2 - a3**2) / (2.0 * a2 * a3))
            if c3 is None:
                continue
            acos_c3 = math.acos(c3)
            q234 = math.atan2(T14[1, 0], T14[0, 0])
            for q3 in (acos_c3, -acos_c3):
                q2 = math.atan2(p13[1], p13[0]) - math.atan2(a3 * math.sin(q3), a2 + a3 * math.cos(q3))
                q4 = q234 - q2 - q3
                solutions.append([q1, q2, q3, q4, q5, q6])
    if not solutions:
        return np.empty((0, 6))
    sols = wrap_to_pi(np.array(solutions))
    T_sols = fk_batch(spec, sols)
    position_error = np.linalg.norm(T_sols[:, :3, 3] - p6, axis=1)
    rotation_error = rotation_distance(T_sols[:, :3, :3], T[:3, :3])
    keep = (position_error <= BRANCH_POSITION_TOL_M) & (rotation_error <= BRANCH_ROTATION_TOL_RAD)
    return sols[keep]


def nearest_in_limits(
    branches: ArrayLike, q_seed: ArrayLike, lower: ArrayLike, upper: ArrayLike
) -> np.ndarray:
    """Each branch moved by whole turns to the representative nearest `q_seed` within [lower, upper].

    Args:
        branches: (K, 6) joint solutions [rad] (any representative of each angle).
        q_seed: (6,) the configuration to stay near [rad], e.g. the arm's current one.
        lower, upper: (6,) joint limits [rad].

    Returns:
        (M, 6) float64, M <= K: the branches that have an in-limit representative, sorted by Euclidean joint
        distance to `q_seed`, nearest first.
    """
    Q = np.asarray(branches, dtype=np.float64).reshape(-1, 6)
    seed = _joint_vector(q_seed, "q_seed")
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    # Shift each angle to the representative nearest the seed, then by one turn back inside the limits.
    shifted = seed + wrap_to_pi(Q - seed)
    shifted = np.where(shifted > hi, shifted - _TWO_PI, shifted)
    shifted = np.where(shifted < lo, shifted + _TWO_PI, shifted)
    ok = np.all((shifted >= lo) & (shifted <= hi), axis=1)
    shifted = shifted[ok]
    order = np.argsort(np.linalg.norm(shifted - seed, axis=1), kind="stable")
    return shifted[order]
