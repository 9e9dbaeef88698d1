"""The one command validator every arm backend runs before acting.

`CommandValidator` checks a joint move, a linear TCP move or a timed trajectory against a frozen
`ValidatorConfig` (joint limits, joint step, speed and acceleration caps, a TCP workspace box, NaN) and
returns the command it will actually send, or raises `UnsafeCommandError` naming the joint, the limit and the
value. Nothing is silently changed unless the config asks for it (`clip_speed=True` lowers a too-high speed or
acceleration argument to the cap and logs it; trajectories are never re-timed).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnsafeCommandError
from prompose_grasp.robot.interfaces import JointCommand, JointTrajectory, LinearCommand
from prompose_grasp.robot.ur_models import JOINT_NAMES

logger = logging.getLogger(__name__)


def _six(values: ArrayLike, name: str) -> tuple[float, ...]:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (6,) or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"ValidatorConfig.{name} must hold 6 finite numbers, got {values!r}")
    return tuple(float(v) for v in arr)


def _three(values: ArrayLike, name: str) -> tuple[float, ...]:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"ValidatorConfig.{name} must hold 3 finite numbers [m], got {values!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class ValidatorConfig:
    """Safety limits for motion commands (SI units). Build one for a robot with `ValidatorConfig.for_robot`.

    Attributes:
        joint_lower_rad, joint_upper_rad: (6,) position limits [rad].
        max_joint_speed_rad_s: (6,) joint speed caps [rad/s]; a `move_joints` speed must not exceed the
            smallest of them (the speed argument applies to the leading joint, whichever that is).
        max_joint_accel_rad_s2: joint acceleration cap [rad/s^2].
        max_move_step_rad: largest change of any joint in one `move_joints` [rad]. pi by default: a bigger
            jump is almost always a wrong IK representative (a wrist spun by a full turn).
        max_waypoint_step_rad: largest change of any joint between consecutive trajectory waypoints (and from
            the current position to the first one) [rad].
        max_tcp_speed_m_s, max_tcp_accel_m_s2: caps of `move_linear` [m/s], [m/s^2].
        workspace_min_m, workspace_max_m: (3,) corners of the box in `base` the TCP must stay in [m].
        clip_speed: lower too-high speed/acceleration arguments to the caps (logged) instead of refusing them.
    """

    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]
    max_joint_speed_rad_s: tuple[float, ...]
    max_joint_accel_rad_s2: float = 4.0
    max_move_step_rad: float = np.pi
    max_waypoint_step_rad: float = 0.2
    max_tcp_speed_m_s: float = 0.5
    max_tcp_accel_m_s2: float = 2.0
    workspace_min_m: tuple[float, ...] = (-1.5, -1.5, -0.5)
    workspace_max_m: tuple[float, ...] = (1.5, 1.5, 1.5)
    clip_speed: bool = field(default=False)

    def __post_init__(self) -> None:
        for name in ("joint_lower_rad", "joint_upper_rad", "max_joint_speed_rad_s"):
            object.__setattr__(self, name, _six(getattr(self, name), name))
        for name in ("workspace_min_m", "workspace_max_m"):
            object.__setattr__(self, name, _three(getattr(self, name), name))
        if any(lo >= hi for lo, hi in zip(self.joint_lower_rad, self.joint_upper_rad)):
            raise InvalidInputError("ValidatorConfig: every joint needs joint_lower_rad < joint_upper_rad")
        if any(lo >= hi for lo, hi in zip(self.workspace_min_m, self.workspace_max_m)):
            raise InvalidInputError(
                "ValidatorConfig: workspace_min_m must be below workspace_max_m on every axis"
            )
        positive = (
            "max_joint_accel_rad_s2",
            "max_move_step_rad",
            "max_waypoint_step_rad",
            "max_tcp_speed_m_s",
            "max_tcp_accel_m_s2",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InvalidInputError(f"ValidatorConfig.{name} must be finite and > 0, got {value!r}")
        if min(self.max_joint_speed_rad_s) <= 0:
            raise InvalidInputError("ValidatorConfig.max_joint_speed_rad_s must be > 0")

    @classmethod
    def for_robot(cls, robot, **overrides) -> ValidatorConfig:
        """Limits of a `RobotModel` (joint range and speed from its UR data) plus any field overrides."""
        lower, upper = robot.joint_limits
        base = cls(joint_lower_rad=lower, joint_upper_rad=upper, max_joint_speed_rad_s=robot.max_joint_speed)
        return replace(base, **overrides)


class CommandValidator:
    """Checks commands against a `ValidatorConfig`; `fk_tcp(q) -> T_base_tcp` enables the workspace check for
    joint commands (linear commands carry their TCP pose)."""

    def __init__(self, config: ValidatorConfig, fk_tcp: Callable[[np.ndarray], np.ndarray] | None = None):
        self.config = config
        self.fk_tcp = fk_tcp
        self._lower = np.array(config.joint_lower_rad)
        self._upper = np.array(config.joint_upper_rad)
        self._vmax = np.array(config.max_joint_speed_rad_s)

    # ------------------------------------------------------------------ pieces
    def _finite_q(self, q: ArrayLike, what: str) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (6,):
            raise UnsafeCommandError(f"{what}: joint target must have shape (6,) [rad], got {q.shape}")
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            j = int(bad[0])
            raise UnsafeCommandError(f"{what}: joint {j} ({JOINT_NAMES[j]}) target is {q[j]} (NaN or inf)")
        return q.copy()

    def _check_limits(self, q: np.ndarray, what: str) -> None:
        outside = np.flatnonzero((q < self._lower) | (q > self._upper))
        if outside.size:
            j = int(outside[0])
            raise UnsafeCommandError(
                f"{what}: joint {j} ({JOINT_NAMES[j]}) target {q[j]:.6g} rad is outside its limits "
                f"[{self._lower[j]:.6g}, {self._upper[j]:.6g}] rad"
            )

    def _check_step(self, q_from: np.ndarray, q_to: np.ndarray, max_step: float, what: str) -> None:
        step = np.abs(q_to - q_from)
        j = int(np.argmax(step))
        if step[j] > max_step:
            raise UnsafeCommandError(
                f"{what}: joint {j} ({JOINT_NAMES[j]}) would move {step[j]:.6g} rad in one step "
                f"(from {q_from[j]:.6g} to {q_to[j]:.6g}); the limit is {max_step:.6g} rad"
            )

    def _check_workspace_point(self, p: np.ndarray, what: str) -> None:
        lo, hi = np.array(self.config.workspace_min_m), np.array(self.config.workspace_max_m)
        outside = np.flatnonzero((p < lo) | (p > hi))
        if outside.size:
            a = int(outside[0])
            raise UnsafeCommandError(
                f"{what}: TCP {'xyz'[a]} = {p[a]:.4f} m is outside the workspace box "
                f"[{lo[a]:.4f}, {hi[a]:.4f}] m (base frame)"
            )

    def _check_workspace_q(self, q: np.ndarray, what: str) -> None:
        if self.fk_tcp is not None:
            self._check_workspace_point(np.asarray(self.fk_tcp(q))[:3, 3], what)

    def _cap(self, value: float, cap: float, name: str, unit: str, what: str) -> float:
        value = float(value)
        if not np.isfinite(value) or value <= 0:
            raise UnsafeCommandError(f"{what}: {name} must be finite and > 0 {unit}, got {value!r}")
        if value > cap:
            if self.config.clip_speed:
                logger.warning(
                    "%s: %s %.4g %s clipped to the cap %.4g %s", what, name, value, unit, cap, unit
                )
                return cap
            raise UnsafeCommandError(f"{what}: {name} {value:.6g} {unit} exceeds the cap {cap:.6g} {unit}")
        return value

    # ------------------------------------------------------------------ commands
    def validate_joint_move(
        self, q_target: ArrayLike, speed: float, accel: float, q_current: ArrayLike | None = None
    ) -> JointCommand:
        """Check a `move_joints`; returns the `JointCommand` to send or raises `UnsafeCommandError`."""
        what = "move_joints"
        q = self.validate_configuration(q_target, q_current, what)
        speed = self._cap(speed, float(np.min(self._vmax)), "joint speed", "rad/s", what)
        accel = self._cap(accel, self.config.max_joint_accel_rad_s2, "joint acceleration", "rad/s^2", what)
        return JointCommand(q=q, speed_rad_s=speed, accel_rad_s2=accel)

    def validate_configuration(
        self, q_target: ArrayLike, q_current: ArrayLike | None = None, what: str = "joint target"
    ) -> np.ndarray:
        """Check a joint configuration the arm will move to: finite, within limits, at most
        `max_move_step_rad`
        from `q_current` on every joint (when given), TCP inside the workspace. Returns a float64 copy."""
        q = self._finite_q(q_target, what)
        self._check_limits(q, what)
        if q_current is not None:
            self._check_step(
                self._finite_q(q_current, "current position"), q, self.config.max_move_step_rad, what
            )
        self._check_workspace_q(q, what)
        return q

    def validate_linear_move(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        """Check a `move_linear` (target pose finite, a rigid transform, inside the workspace; speed caps)."""
        what = "move_linear"
        T = np.asarray(T_base_tcp, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise UnsafeCommandError(
                f"{what}: T_base_tcp must be a finite (4, 4) transform, got shape {T.shape}"
            )
        R = T[:3, :3]
        if (
            not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0
            or not np.allclose(T[3], [0, 0, 0, 1])
        ):
            raise UnsafeCommandError(f"{what}: T_base_tcp is not a rigid transform")
        self._check_workspace_point(T[:3, 3], what)
        speed = self._cap(speed, self.config.max_tcp_speed_m_s, "TCP speed", "m/s", what)
        accel = self._cap(accel, self.config.max_tcp_accel_m_s2, "TCP acceleration", "m/s^2", what)
        return LinearCommand(T_base_tcp=T.copy(), speed_m_s=speed, accel_m_s2=accel)

    def validate_trajectory(self, trajectory: JointTrajectory, q_current: ArrayLike) -> JointTrajectory:
        """Check a timed trajectory from `q_current`: every waypoint finite, in limits and in the workspace,
        consecutive steps below `max_waypoint_step_rad`, joint speeds (finite differences) below the caps and
        accelerations below `max_joint_accel_rad_s2`. Returns a copy of the trajectory that will be sent."""
        what = "follow"
        if not isinstance(trajectory, JointTrajectory):
            raise UnsafeCommandError(f"{what}: expected a JointTrajectory, got {type(trajectory).__name__}")
        current = self._finite_q(q_current, "current position")
        Q = np.vstack([current, trajectory.q])
        t = np.concatenate([[0.0], trajectory.t_s])
        for k, q in enumerate(trajectory.q):
            where = f"{what} waypoint {k}"
            self._finite_q(q, where)
            self._check_limits(q, where)
            self._check_step(Q[k], q, self.config.max_waypoint_step_rad, where)
            self._check_workspace_q(q, where)
        dt = np.diff(t)
        moving = dt > 0
        # A first waypoint at t = 0 must be the current position (checked by the step test); no speed from it.
        v = np.zeros((len(dt), 6))
        v[moving] = np.diff(Q, axis=0)[moving] / dt[moving, None]
        ratio = np.abs(v) / self._vmax
        k, j = (int(i) for i in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
        if ratio[k, j] > 1.0:
            raise UnsafeCommandError(
                f"{what}: joint {j} ({JOINT_NAMES[j]}) would move at {abs(v[k, j]):.6g} rad/s "
                f"before waypoint {k}; its speed limit is {self._vmax[j]:.6g} rad/s"
            )
        if len(dt) >= 2:
            t_mid = 0.5 * (t[1:] + t[:-1])
            dt_mid = np.diff(t_mid)
            a = np.diff(v, axis=0) / np.where(dt_mid > 0, dt_mid, np.inf)[:, None]
            k, j = (int(i) for i in np.unravel_index(int(np.argmax(np.abs(a))), a.shape))
            if abs(a[k, j]) > self.config.max_joint_accel_rad_s2:
                raise UnsafeCommandError(
                    f"{what}: joint {j} ({JOINT_NAMES[j]}) would accelerate at {abs(a[k, j]):.6g} rad/s^2 "
                    f"around waypoint {k}; the cap is {self.config.max_joint_accel_rad_s2:.6g} rad/s^2"
                )
        return JointTrajectory(t_s=trajectory.t_s.copy(), q=trajectory.q.copy())
