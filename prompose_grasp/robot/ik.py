"""Inverse kinematics for the UR arms: closed form, mink differential IK, and a Pinocchio CLIK cross-check.

The closed form (`kinematics.ik_branches`) gives every exact solution of the 6-DoF arm (up to 8 branches, each
valid modulo whole turns). It is the default: the branch nearest the seed that lies within the joint limits
and clears the support plane. The iterative solvers exist for what the closed form cannot express (the support
plane as a hard constraint of a descent, velocity limits) and as independent checks:

- `mink`: differential IK on the MuJoCo model (QP solved by daqp, `ConfigurationLimit`, and
  `CollisionAvoidanceLimit` between the arm's capsules and the support plane when one is configured), started
  from the closed-form branches nearest the seed (default) or from the seed plus random restarts.
- `pinocchio`: damped Gauss-Newton on the SE(3) log error (CLIK) on the Pinocchio model, same seeding.

No posture task is used: it would pull the solution off the target (a 6-DoF arm has no null space to spend it
in). Every result reports errors measured by closed-form forward kinematics, independent of the solver.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.robot.kinematics import (
    fk,
    fk_batch,
    ik_branches,
    nearest_in_limits,
    rotation_distance,
    wrap_to_pi,
)
from prompose_grasp.robot.ur_models import URSpec

logger = logging.getLogger(__name__)

IKMethod = Literal["closed_form", "mink", "pinocchio"]
IK_METHODS: tuple[str, ...] = ("closed_form", "mink", "pinocchio")


@dataclass(frozen=True)
class IKConfig:
    """Settings of an IK solve.

    Attributes:
        position_tol_m: a solution must place the target frame within this distance [m].
        rotation_tol_rad: ... and within this geodesic angle [rad]. The iterative solvers converge to these;
            the closed form is exact (~1e-12) and only checked against them.
        max_iterations: iterations per seed for the iterative solvers.
        max_seeds: seeds tried by the iterative solvers before giving up.
        closed_form_seeds: seed the iterative solvers with the closed-form branches nearest the seed (True),
            or with the seed followed by random in-limit configurations (False: "the solver on its own").
        random_seed: RNG seed for the random restarts, so a solve is reproducible.
        support_plane_z_m: height of the support plane in the base frame [m], or None for no plane. Arm links
            (all but `base` and `shoulder_link`, which sit on it) must stay above it.
        support_clearance_m: minimum distance between the arm's capsules and the support plane [m].
        lm_damping: Levenberg-Marquardt damping of the iterative solvers (scaled by the squared error).
        max_step_rad: largest change of any joint in one iterative step [rad] (a trust region: full
            Gauss-Newton steps from far away overshoot into the joint limits).
        stall_window: an iterative solve from one seed stops when this many steps brought no 1 % improvement.
    """

    position_tol_m: float = 1e-5
    rotation_tol_rad: float = 1e-5
    max_iterations: int = 60
    max_seeds: int = 8
    closed_form_seeds: bool = True
    random_seed: int = 0
    support_plane_z_m: float | None = None
    support_clearance_m: float = 0.005
    lm_damping: float = 1e-3
    stall_window: int = 10
    max_step_rad: float = 0.5

    def __post_init__(self) -> None:
        if not (self.position_tol_m > 0 and self.rotation_tol_rad > 0):
            raise InvalidInputError("IKConfig tolerances must be positive")
        if self.max_iterations < 1 or self.max_seeds < 1:
            raise InvalidInputError("IKConfig.max_iterations and max_seeds must be >= 1")
        if self.support_clearance_m < 0 or self.lm_damping < 0:
            raise InvalidInputError("IKConfig.support_clearance_m and lm_damping must be >= 0")


@dataclass(frozen=True)
class IKResult:
    """Outcome of one IK solve.

    Attributes:
        q: (6,) float64 joint configuration [rad]; on failure, the best configuration found (or the seed).
        success: True when `q` is within the joint limits, clears the support plane (if any) and reaches the
            target within the configured tolerances.
        position_error_m: distance between the reached and the target frame origin [m].
        rotation_error_rad: geodesic angle between the reached and the target orientation [rad].
        iterations: solver iterations summed over seeds (0 for the closed form).
        solve_time_s: wall time of the solve [s].
        method: "closed_form", "mink" or "pinocchio".
        message: why a solve failed ("" on success).
    """

    q: np.ndarray
    success: bool
    position_error_m: float
    rotation_error_rad: float
    iterations: int
    solve_time_s: float
    method: str = "closed_form"
    message: str = field(default="", compare=False)


def pose_errors(T_reached: np.ndarray, T_target: np.ndarray) -> tuple[float, float]:
    """(position error [m], rotation error [rad]) between two (4, 4) poses."""
    return (
        float(np.linalg.norm(T_reached[:3, 3] - T_target[:3, 3])),
        float(rotation_distance(T_reached[:3, :3], T_target[:3, :3])),
    )


class IKArm(Protocol):
    """What the solvers need of an arm model (`RobotModel` is one): its kinematic table, joint limits and
    names, the support-plane check, and the Pinocchio / MuJoCo models the iterative methods run on. The
    solvers are functions of such a model; the model module calls them, never the reverse."""

    spec: URSpec
    joint_names: tuple[str, ...]

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]: ...

    @property
    def pin_model(self) -> Any: ...

    @property
    def mj_model_with_plane(self) -> Any: ...

    @property
    def plane_checked_geoms(self) -> tuple[str, ...]: ...

    def clears_support(self, q: np.ndarray, config: IKConfig) -> bool: ...


class IKProblem:
    """Bookkeeping shared by the methods: target in flange terms, seed, limits, and the final result."""

    def __init__(self, robot: IKArm, T_base_flange_target: np.ndarray, q_seed: np.ndarray, config: IKConfig):
        self.robot = robot
        self.T_target = T_base_flange_target
        self.q_seed = q_seed
        self.config = config
        self.lower, self.upper = robot.joint_limits
        self.t0 = time.perf_counter()

    def ok(self, q: np.ndarray) -> tuple[bool, float, float]:
        pos, rot = pose_errors(fk(self.robot.spec, q), self.T_target)
        reached = pos <= self.config.position_tol_m and rot <= self.config.rotation_tol_rad
        return reached and self.admissible(q), pos, rot

    def admissible(self, q: np.ndarray) -> bool:
        in_limits = bool(np.all(q >= self.lower - 1e-12) and np.all(q <= self.upper + 1e-12))
        return in_limits and self.robot.clears_support(q, self.config)

    def result(self, q: np.ndarray, iterations: int, method: str, message: str = "") -> IKResult:
        success, pos, rot = self.ok(q)
        if not success and not message:
            message = (
                f"no admissible solution: best has position error {pos:.3g} m, rotation error {rot:.3g} rad "
                f"(tolerances {self.config.position_tol_m:g} m, {self.config.rotation_tol_rad:g} rad)"
            )
        return IKResult(
            q=np.array(q, dtype=np.float64),
            success=success,
            position_error_m=pos,
            rotation_error_rad=rot,
            iterations=iterations,
            solve_time_s=time.perf_counter() - self.t0,
            method=method,
            message="" if success else message,
        )

    def closed_form_candidates(self) -> np.ndarray:
        """(M, 6) in-limit closed-form branches nearest the seed first (support plane not yet applied)."""
        branches = ik_branches(self.robot.spec, self.T_target, q6_if_singular=float(self.q_seed[5]))
        return nearest_in_limits(branches, self.q_seed, self.lower, self.upper)

    def seeds(self) -> np.ndarray:
        """(S, 6) start configurations for the iterative solvers, at most `max_seeds`."""
        cfg = self.config
        if cfg.closed_form_seeds:
            candidates = self.closed_form_candidates()
            admissible = [q for q in candidates if self.robot.clears_support(q, cfg)]
            # Colliding branches still make useful starts: the constrained solver may slide off the plane.
            rest = [q for q in candidates if not self.robot.clears_support(q, cfg)]
            seeds = np.array(admissible + rest).reshape(-1, 6)
            return seeds[: cfg.max_seeds]
        rng = np.random.default_rng(cfg.random_seed)
        extra = rng.uniform(self.lower, self.upper, size=(cfg.max_seeds - 1, 6))
        # Angles are equivalent modulo a turn; starting each joint in (-pi, pi] keeps the descent away from
        # the +-2 pi limits it would otherwise run into. `near_seed` moves the answer back next to the seed.
        return wrap_to_pi(np.vstack([self.q_seed, extra]))

    def near_seed(self, q: np.ndarray) -> np.ndarray:
        """q moved by whole turns to the in-limit representative nearest the seed (q itself if none)."""
        moved = nearest_in_limits(q[None, :], self.q_seed, self.lower, self.upper)
        return moved[0] if len(moved) else q


def solve_closed_form(solve: IKProblem) -> IKResult:
    candidates = solve.closed_form_candidates()
    if len(candidates) == 0:
        branches = ik_branches(solve.robot.spec, solve.T_target)
        why = (
            "out of reach (no closed-form branch)"
            if len(branches) == 0
            else "every branch is outside the limits"
        )
        return solve.result(solve.q_seed, 0, "closed_form", why)
    for q in candidates:
        if solve.robot.clears_support(q, solve.config):
            return solve.result(q, 0, "closed_form")
    return solve.result(candidates[0], 0, "closed_form", "every branch collides with the support plane")


class MinkIK:
    """mink differential IK on the arm's MuJoCo model (daqp; joint limits; support-plane avoidance)."""

    def __init__(self, robot: IKArm):
        import mink
        import mujoco

        self._mink = mink
        self._mujoco = mujoco
        self.robot = robot
        self.model = robot.mj_model_with_plane
        self.configuration = mink.Configuration(self.model)
        self._plane_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, "support_plane")
        self._flange_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "flange")
        self.task = mink.FrameTask("flange", "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-3)
        self.configuration_limit = mink.ConfigurationLimit(self.model)
        self.collision_limit = mink.CollisionAvoidanceLimit(
            self.model,
            geom_pairs=[(list(robot.plane_checked_geoms), ["support_plane"])],
            minimum_distance_from_collisions=0.005,
            collision_detection_distance=0.05,
        )

    def _limits(self, config: IKConfig) -> list:
        # Pseudo-time dt = 1, so this velocity limit is a trust region on each Gauss-Newton step [rad].
        step = self._mink.VelocityLimit(self.model, {n: config.max_step_rad for n in self.robot.joint_names})
        limits: list = [self.configuration_limit, step]
        if config.support_plane_z_m is not None:
            self.model.geom_pos[self._plane_id, 2] = config.support_plane_z_m
            self.collision_limit.minimum_distance_from_collisions = config.support_clearance_m
            limits.append(self.collision_limit)
        return limits

    def solve(self, solve: IKProblem) -> IKResult:
        cfg = solve.config
        self.task.lm_damping = cfg.lm_damping
        self.task.set_target(self._mink.SE3.from_matrix(solve.T_target))
        limits = self._limits(cfg)
        best_q, best_err, total_iterations = solve.q_seed, np.inf, 0
        for seed in solve.seeds():
            q, iterations, _ = self._descend(seed, solve, limits)
            total_iterations += iterations
            q = solve.near_seed(q)
            success, pos, rot = solve.ok(q)
            if success:
                return solve.result(q, total_iterations, "mink")
            if pos + rot < best_err:
                best_q, best_err = q, pos + rot
        return solve.result(best_q, total_iterations, "mink")

    def _descend(self, seed: np.ndarray, solve: IKProblem, limits: list) -> tuple[np.ndarray, int, float]:
        conf, cfg = self.configuration, solve.config
        conf.update(np.clip(seed, solve.lower, solve.upper))
        data = conf.data
        history: list[float] = []
        for iteration in range(cfg.max_iterations):
            pos = float(np.linalg.norm(data.site_xpos[self._flange_site] - solve.T_target[:3, 3]))
            rot = float(
                rotation_distance(data.site_xmat[self._flange_site].reshape(3, 3), solve.T_target[:3, :3])
            )
            if pos <= cfg.position_tol_m and rot <= cfg.rotation_tol_rad:
                return conf.q, iteration, pos + rot
            if _stalled(history, pos + rot, cfg.stall_window):
                return conf.q, iteration, pos + rot
            try:
                velocity = self._mink.solve_ik(conf, [self.task], 1.0, "daqp", damping=1e-12, limits=limits)
            except self._mink.NoSolutionFound:
                return conf.q, iteration, pos + rot
            conf.integrate_inplace(velocity, 1.0)
        return conf.q, cfg.max_iterations, history[-1]


class PinocchioCLIK:
    """Closed-loop IK on the Pinocchio model: damped Gauss-Newton on log6(oMf^-1 oMdes), clipped to limits."""

    def __init__(self, robot: IKArm):
        import pinocchio as pin

        self.pin = pin
        self.robot = robot
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.frame_id = self.model.getFrameId("flange")

    def solve(self, solve: IKProblem) -> IKResult:
        pin, cfg = self.pin, solve.config
        oMdes = pin.SE3(solve.T_target[:3, :3], solve.T_target[:3, 3])
        best_q, best_err, total_iterations = solve.q_seed, np.inf, 0
        for seed in solve.seeds():
            q = np.clip(seed, solve.lower, solve.upper)
            history: list[float] = []
            for _ in range(cfg.max_iterations):
                total_iterations += 1
                pin.framesForwardKinematics(self.model, self.data, q)
                iMd = self.data.oMf[self.frame_id].actInv(oMdes)
                err = pin.log6(iMd).vector  # (v, omega) in the flange frame
                pos, rot = float(np.linalg.norm(iMd.translation)), float(np.linalg.norm(err[3:]))
                if (pos <= cfg.position_tol_m and rot <= cfg.rotation_tol_rad) or _stalled(
                    history, pos + rot, cfg.stall_window
                ):
                    break
                J = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id, pin.LOCAL)
                J = -pin.Jlog6(iMd.inverse()) @ J
                damping = cfg.lm_damping * float(err @ err) + 1e-12
                dq = -J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), err)
                # Same trust region as the mink path: scale the step so no joint moves more than max_step_rad.
                dq *= min(1.0, cfg.max_step_rad / max(float(np.max(np.abs(dq))), 1e-300))
                q = np.clip(q + dq, solve.lower, solve.upper)
            q = solve.near_seed(q)
            success, pos, rot = solve.ok(q)
            if success:
                return solve.result(q, total_iterations, "pinocchio")
            if pos + rot < best_err:
                best_q, best_err = q, pos + rot
        return solve.result(best_q, total_iterations, "pinocchio")


def _stalled(history: list[float], error: float, window: int) -> bool:
    """Record `error`; True when the best error of the last `window` steps is no better than 0.99x the best
    before them (a local minimum, or a target blocked by a limit). Gauss-Newton steps far from the
    solution are not monotone, so a single worse step is no reason to stop."""
    history.append(error)
    if len(history) <= window:
        return False
    return min(history[-window:]) > 0.99 * min(history[:-window])


def check_method(method: str) -> str:
    if method not in IK_METHODS:
        raise UnknownNameError("IK method", method, IK_METHODS)
    return method


def batch_fk_errors(robot: IKArm, Q: np.ndarray, T_targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position [m] and rotation [rad] errors (N,) of configurations Q (N, 6) vs flange targets (N, 4, 4)."""
    T = fk_batch(robot.spec, Q)
    return (
        np.linalg.norm(T[:, :3, 3] - T_targets[:, :3, 3], axis=1),
        rotation_distance(T[:, :3, :3], T_targets[:, :3, :3]),
    )
