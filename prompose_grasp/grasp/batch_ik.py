"""Closed-form UR inverse kinematics for many targets at once (numpy over N targets x 8 branches).

`RobotModel.ik_all` solves one target in about a millisecond of Python; grasp ranking needs hundreds of
targets in a few milliseconds. This is the same derivation as `prompose_grasp.robot.kinematics.ik_branches`
(wrist-2 centre on the plane at d4 from the base axis -> q1; tool z -> q5; tool x/y -> q6; planar 2R -> q3,
then q2, q4), written on arrays, and every branch is verified by the robot layer's batched forward kinematics
(`fk_batch`) with the robot layer's tolerances, so a returned solution is exact or absent. Tests compare it
with `ik_branches` on random targets.
"""

from __future__ import annotations

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.robot.kinematics import (
    BRANCH_POSITION_TOL_M,
    BRANCH_ROTATION_TOL_RAD,
    dh_transforms,
    fk_batch,
    rotation_distance,
)
from prompose_grasp.robot.ur_models import URSpec

__all__ = [
    "FK_REACH_TOL",
    "branch_order",
    "fk_reaches",
    "ik_branches_batch",
    "ik_nearest_batch",
    "link_frames_batch",
    "nearest_in_limits_batch",
]

# Same meaning and values as in robot.kinematics (arcsin/arccos argument slack, wrist singularity).
_ARG_SLACK = 1e-9
_WRIST_SINGULAR_SIN = 1e-10
_TWO_PI = 2.0 * np.pi


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a stack of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _wrap(a: np.ndarray) -> np.ndarray:
    """`wrap_to_pi` (angles to (-pi, pi]) with floor instead of mod: the same values up to rounding, a few
    times faster on the (N, 8, 6) branch arrays."""
    w = a - _TWO_PI * np.floor((a + np.pi) / _TWO_PI)
    return np.where(w <= -np.pi, w + _TWO_PI, w)


def _clip_arg(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(clipped x, ok): arguments overshooting [-1, 1] by more than the slack have no real angle."""
    ok = np.abs(x) <= 1.0 + _ARG_SLACK
    return np.clip(x, -1.0, 1.0), ok


def ik_branches_batch(
    spec: URSpec, T_base_flange: np.ndarray, q6_if_singular: float | np.ndarray = 0.0, verify: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """All closed-form solutions of N flange poses.

    Args:
        spec: the arm.
        T_base_flange: (N, 4, 4) float64 target flange poses in `base` [m].
        q6_if_singular: q6 [rad] used where the wrist is singular (q6 is free there); a scalar or (N,).
        verify: check every branch by forward kinematics (False: only the arccos/arcsin domains are checked,
            for callers that verify the branches they pick, as `ik_nearest_batch` does).

    Returns:
        (Q, valid): Q (N, 8, 6) float64 joint angles in (-pi, pi] [rad], branch order shoulder x wrist x
        elbow as `ik_branches`; valid (N, 8) bool, True where the branch exists and its forward kinematics
        reproduce the target within `BRANCH_POSITION_TOL_M` / `BRANCH_ROTATION_TOL_RAD`. Joint limits are not
        applied (see `nearest_in_limits_batch`).
    """
    T = np.asarray(T_base_flange, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InvalidInputError(f"T_base_flange must have shape (N, 4, 4), got {T.shape}")
    n = T.shape[0]
    if n == 0:
        return np.zeros((0, 8, 6)), np.zeros((0, 8), dtype=bool)
    d1, a2, a3, d4, d5, d6 = spec.d1, spec.a2, spec.a3, spec.d4, spec.d5, spec.d6
    alpha = spec.alpha_rad
    x6, y6, z6, p6 = T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3]
    p5 = p6 - d6 * z6
    r = np.hypot(p5[:, 0], p5[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        s, ok_s = _clip_arg(np.where(r > 1e-12, d4 / np.maximum(r, 1e-300), 2.0))
    phi = np.arctan2(p5[:, 1], p5[:, 0])
    asin_s = np.arcsin(s)
    q1 = np.stack([phi + asin_s, phi + np.pi - asin_s], axis=1)  # (N, 2)
    ok1 = np.repeat(ok_s[:, None], 2, axis=1)

    s1, c1 = np.sin(q1), np.cos(q1)
    # n: the common direction of the parallel joint axes 2, 3, 4 (z1 in base coordinates).
    nvec = np.stack([s1, -c1, np.zeros_like(s1)], axis=-1)  # (N, 2, 3)
    c5, ok5 = _clip_arg((np.einsum("nkj,nj->nk", nvec, p6) - d4) / d6)
    acos_c5 = np.arccos(c5)
    q5 = np.stack([acos_c5, -acos_c5], axis=2)  # (N, 2, 2)
    ok15 = (ok1 & ok5)[:, :, None].repeat(2, axis=2)
    s5 = np.sin(q5)
    sign = np.where(s5 > 0, 1.0, -1.0)
    xn = np.einsum("nkj,nj->nk", nvec, x6)[:, :, None]
    yn = np.einsum("nkj,nj->nk", nvec, y6)[:, :, None]
    q6_free = np.broadcast_to(np.asarray(q6_if_singular, dtype=np.float64).reshape(-1, 1, 1), (n, 2, 2))
    q6 = np.where(np.abs(s5) < _WRIST_SINGULAR_SIN, q6_free, np.arctan2(-sign * yn, sign * xn))  # (N, 2, 2)

    q1e = np.broadcast_to(q1[:, :, None], (n, 2, 2)).reshape(-1)
    T01_inv = _inv(dh_transforms(q1e, d1, 0.0, alpha[0]))
    T45_inv = _inv(dh_transforms(q5.reshape(-1), d5, 0.0, alpha[4]))
    T56_inv = _inv(dh_transforms(q6.reshape(-1), d6, 0.0, alpha[5]))
    Te = np.broadcast_to(T[:, None, None], (n, 2, 2, 4, 4)).reshape(-1, 4, 4)
    T14 = T01_inv @ Te @ T56_inv @ T45_inv  # (4N, 4, 4)
    # Frame 3's origin sits d4 back along z3 = y4 from frame 4's origin.
    p13 = -d4 * T14[:, :3, 1] + T14[:, :3, 3]
    c3, ok3 = _clip_arg((p13[:, 0] ** 2 + p13[:, 1] ** 2 - a2**2 - a3**2) / (2.0 * a2 * a3))
    acos_c3 = np.arccos(c3)
    q3 = np.stack([acos_c3, -acos_c3], axis=1)  # (4N, 2)
    q234 = np.arctan2(T14[:, 1, 0], T14[:, 0, 0])[:, None]
    q2 = np.arctan2(p13[:, 1], p13[:, 0])[:, None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q4 = q234 - q2 - q3

    Q = np.stack(
        [
            np.repeat(q1e[:, None], 2, axis=1),
            q2,
            q3,
            q4,
            np.repeat(q5.reshape(-1)[:, None], 2, axis=1),
            np.repeat(q6.reshape(-1)[:, None], 2, axis=1),
        ],
        axis=-1,
    ).reshape(n, 8, 6)
    valid = np.repeat((ok15.reshape(-1) & ok3)[:, None], 2, axis=1).reshape(n, 8)
    Q = _wrap(Q)
    if not verify:
        return Q, valid
    # Verify by forward kinematics (the branches that do not exist give garbage that FK rejects).
    Tq = fk_batch(spec, Q.reshape(-1, 6)).reshape(n, 8, 4, 4)
    pos_err = np.linalg.norm(Tq[..., :3, 3] - p6[:, None, :], axis=-1)
    rot_err = rotation_distance(Tq[..., :3, :3], T[:, None, :3, :3])
    valid &= (pos_err <= BRANCH_POSITION_TOL_M) & (rot_err <= BRANCH_ROTATION_TOL_RAD)
    return Q, valid


def nearest_in_limits_batch(
    Q: np.ndarray, valid: np.ndarray, q_seed: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Branches moved by whole turns to the in-limit representative nearest `q_seed`, ranked by distance.

    Args:
        Q: (N, K, 6) branches [rad]; valid: (N, K) bool.
        q_seed: (6,) configuration to stay near, or (N, 6) one per target [rad]; lower, upper: (6,) joint
            limits [rad].

    Returns:
        (Q_shifted (N, K, 6), ok (N, K) valid and within limits, distance (N, K) Euclidean joint distance to
        the seed, inf where not ok).
    """
    seed = np.asarray(q_seed, dtype=np.float64)
    if seed.ndim == 2:
        seed = seed[:, None, :]
    shifted = seed + _wrap(Q - seed)
    shifted = np.where(shifted > upper, shifted - _TWO_PI, shifted)
    shifted = np.where(shifted < lower, shifted + _TWO_PI, shifted)
    ok = valid & np.all((shifted >= lower) & (shifted <= upper), axis=-1)
    dist = np.where(ok, np.linalg.norm(shifted - seed, axis=-1), np.inf)
    return shifted, ok, dist


def ik_nearest_batch(
    spec: URSpec,
    T_base_flange: np.ndarray,
    q_seed: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each of N flange poses, the verified in-limit closed-form solution nearest `q_seed`.

    Cheaper than `ik_branches_batch` followed by a choice: the 8 N branches are computed without forward
    kinematics, the nearest in-limit one per target is picked, and only the picks are verified by forward
    kinematics; a pick that fails verification is dropped and the next nearest branch taken (this happens
    only at the edge of the workspace).

    Args:
        spec: the arm; T_base_flange: (N, 4, 4) targets; q_seed: (6,) or (N, 6) [rad]; lower, upper: (6,).

    Returns:
        (q (N, 6) [rad] (NaN where none), ok (N,) bool, branches (N, 8, 6) all in-limit representatives with
        NaN rows where a branch does not exist or is outside the limits, nearest first).
    """
    T = np.asarray(T_base_flange, dtype=np.float64)
    n = T.shape[0]
    seed = np.asarray(q_seed, dtype=np.float64)
    # Early out (sound): the wrist-2 centre is at most sqrt((|a2| + |a3| + d5)^2 + d4^2) from the shoulder
    # (a2, a3, d5 lie in the arm's plane, d4 normal to it); the rows beyond have no branch at all.
    p5 = T[:, :3, 3] - spec.d6 * T[:, :3, 2]
    reach2 = (abs(spec.a2) + abs(spec.a3) + abs(spec.d5)) ** 2 + spec.d4**2
    near = np.sum((p5 - [0.0, 0.0, spec.d1]) ** 2, axis=1) <= reach2 * (1.0 + 1e-9)
    if not np.all(near):
        q_out = np.full((n, 6), np.nan)
        ok_out = np.zeros(n, dtype=bool)
        br_out = np.full((n, 8, 6), np.nan)
        rows = np.flatnonzero(near)
        if rows.size:
            s = seed[rows] if seed.ndim == 2 else seed
            q_out[rows], ok_out[rows], br_out[rows] = ik_nearest_batch(spec, T[rows], s, lower, upper)
        return q_out, ok_out, br_out
    Q, valid = _branches_by_z_turns(spec, T, seed)
    shifted, ok, dist = nearest_in_limits_batch(Q, valid, seed, lower, upper)
    order = np.argsort(dist, axis=1, kind="stable")
    shifted = np.take_along_axis(shifted, order[:, :, None], axis=1)
    ok = np.take_along_axis(ok, order, axis=1)
    verified = np.zeros_like(ok)
    rows = np.arange(n)
    pick = np.zeros(n, dtype=np.int64)
    pending = ok[:, 0].copy()
    for _ in range(8):
        idx = rows[pending]
        if idx.size == 0:
            break
        q = shifted[idx, pick[idx]]
        Tq = fk_batch(spec, q)
        good = (np.linalg.norm(Tq[:, :3, 3] - T[idx, :3, 3], axis=1) <= BRANCH_POSITION_TOL_M) & (
            rotation_distance(Tq[:, :3, :3], T[idx, :3, :3]) <= BRANCH_ROTATION_TOL_RAD
        )
        verified[idx[good], pick[idx[good]]] = True
        bad = idx[~good]
        ok[bad, pick[bad]] = False
        # Next candidate branch for the failures: the next one that is still ok.
        nxt = pick[bad] + 1
        pending[:] = False
        for i, k in zip(bad, nxt):
            while k < 8 and not ok[i, k]:
                k += 1
            if k < 8:
                pick[i] = k
                pending[i] = True
    found = verified.any(axis=1)
    q_out = np.full((n, 6), np.nan)
    q_out[found] = shifted[found, pick[found]]
    # The unpicked branches are left unverified; the picked ones that failed are marked NaN.
    shifted = np.where(ok[:, :, None], shifted, np.nan)
    return q_out, np.asarray(found, dtype=bool), shifted


#: A configuration reaches a flange pose when its forward kinematics lands within this of it, in position [m]
#: and in the Frobenius norm of the rotation difference [-] (exact closed-form solutions land at ~1e-15).
FK_REACH_TOL = 1e-7


def fk_reaches(T_fk: np.ndarray, T_base_flange: np.ndarray) -> np.ndarray:
    """(...,) True where forward-kinematics poses `T_fk` (..., 4, 4) equal the flange poses `T_base_flange`
    (..., 4, 4) within `FK_REACH_TOL`: the check for a branch not verified when it was solved."""
    T_fk, T = np.asarray(T_fk, dtype=np.float64), np.asarray(T_base_flange, dtype=np.float64)
    return (np.linalg.norm(T_fk[..., :3, 3] - T[..., :3, 3], axis=-1) <= FK_REACH_TOL) & (
        np.linalg.norm(T_fk[..., :3, :3] - T[..., :3, :3], axis=(-2, -1)) <= FK_REACH_TOL
    )


def branch_order(q_first: np.ndarray, branches: np.ndarray) -> list[np.ndarray]:
    """The picked solution `q_first` (6,) first, then the other existing branches of `branches` (8, 6)
    (`ik_nearest_batch`'s, nearest the seed first; NaN rows absent) that differ from it."""
    out = [q_first]
    for q in branches:
        # Same configuration up to rounding (the branches come from the same arithmetic).
        if np.all(np.isfinite(q)) and float(np.max(np.abs(q - q_first))) > 1e-9:
            out.append(q)
    return out


def _branches_unverified(spec: URSpec, T: np.ndarray, q6_if_singular) -> tuple[np.ndarray, np.ndarray]:
    return ik_branches_batch(spec, T, q6_if_singular, verify=False)


def _branches_by_z_turns(spec: URSpec, T: np.ndarray, seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_branches_unverified` solved once per distinct (flange position, flange z axis).

    Targets that differ only by a turn phi about the flange's own z axis (a grasp and its flip, the yaws of a
    suction cup: the tcp lies on that axis) differ only in q6: joint 6 turns the flange about that axis
    (alpha6 = a6 = 0), so every branch of T Rz(phi) is the branch of T with q6 + phi. Candidates come in such
    groups of 2 (jaw flips) to 4 (cup yaws), so this halves to quarters the closed-form work."""
    n = len(T)
    key = np.ascontiguousarray(np.concatenate([T[:, :3, 3], T[:, :3, 2]], axis=1))
    # Rows as 48-byte strings: unique on a 1-D array (bitwise equality, cheaper than unique(axis=0)).
    key = key.view(np.dtype((np.void, key.dtype.itemsize * 6))).ravel()
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    q6_seed = seed[..., 5] if seed.ndim == 1 else seed[first, 5]
    if len(first) == n:
        return _branches_unverified(spec, T, seed[..., 5])
    Q1, valid1 = _branches_unverified(spec, T[first], q6_seed)
    # The turn about z taking each group's first target to the member: R_first^T R = Rz(phi).
    R_rel = np.swapaxes(T[first[inverse], :3, :3], 1, 2) @ T[:, :3, :3]
    phi = np.arctan2(R_rel[:, 1, 0], R_rel[:, 0, 0])
    Q = Q1[inverse]
    Q[..., 5] = _wrap(Q[..., 5] + phi[:, None])
    return Q, valid1[inverse]


def link_frames_batch(spec: URSpec, Q: np.ndarray) -> np.ndarray:
    """(N, 8, 4, 4) poses in `base` of the URDF link frames base, shoulder_link .. wrist_3_link, flange for N
    configurations Q (N, 6) [rad]: `RobotModel.link_frames` on arrays (URDF link i+1 is DH frame i turned by
    q_i about its z; the flange is DH frame 6)."""
    Q = np.asarray(Q, dtype=np.float64)
    if Q.ndim != 2 or Q.shape[1] != 6:
        raise InvalidInputError(f"Q must have shape (N, 6) [rad], got {Q.shape}")
    n = Q.shape[0]
    out = np.empty((n, 8, 4, 4))
    out[:, 0] = np.eye(4)
    F = np.broadcast_to(np.eye(4), (n, 4, 4))
    for i in range(6):
        out[:, i + 1] = F @ dh_transforms(Q[:, i], 0.0, 0.0, 0.0)
        F = F @ dh_transforms(Q[:, i], spec.d_m[i], spec.a_m[i], spec.alpha_rad[i])
    out[:, 7] = F
    return out
