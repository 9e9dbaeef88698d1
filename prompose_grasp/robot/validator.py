"""The one command validator every arm backend runs before acting.

`CommandValidator` checks a joint move, a linear TCP move or a timed trajectory against a frozen
`ValidatorConfig` and returns the command it will actually send, or raises:

- `InvalidInputError` for an argument of the wrong type, dtype or shape. Nothing is coerced: vectors are numpy
  arrays of real floats or ints or lists / tuples of Python floats and ints (ints are converted exactly),
  speeds are real numbers; bools, complex numbers, strings, None, dicts and 0-d arrays are refused
  (`robot.real_numbers`).
- `UnsafeCommandError` for a command outside the limits, naming the joint, the limit and the value: NaN,
  joint limits, joint step, speed, acceleration, start position, TCP workspace.

Nothing is silently changed unless the config asks for it (`clip_speed=True` lowers a too-high speed or
acceleration argument of a joint or linear move to the cap and logs it; trajectories are never re-timed).

Workspace along joint-space lines. With `fk_tcp` set, a joint move and every trajectory segment are checked
along the straight joint-space line they follow (moveJ and servoJ interpolate linearly in joint space), not
only at their ends: the line is sampled, both ends included, so that no joint moves more than
`workspace_step_rad` between samples. (A move from a position outside the box is refused: the arm has left
the box already, and the first stretch of the line is outside too.) A joint step dq moves the TCP by at most
sum_j |dq_j| r_j, r_j the TCP's distance from joint j's axis, which the link lengths beyond joint j plus the
tool bound: sum_j r_j <= 4.3 m for a UR5e with a 15 cm tool (5.5 m for a UR10e, the longest arm). Every
point of the line is within half a step of a sample on every joint, so with the default 0.005 rad the TCP
leaves the box between samples by at most 0.0025 rad * 4.3 m = 1.1 cm (1.4 cm on a UR10e): draw the box that
much inside what must not be crossed. A linear move needs no sampling: its TCP line runs from where the arm
is (inside the box, where the last checked command left it) to a target inside it, and the box is convex.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnsafeCommandError
from prompose_grasp.robot.interfaces import JointCommand, JointTrajectory, LinearCommand
from prompose_grasp.robot.real_numbers import real_array, real_number
from prompose_grasp.robot.ur_models import JOINT_NAMES

logger = logging.getLogger(__name__)

#: Relative allowance on the speed and acceleration caps of a trajectory, for the rounding of its finite
#: differences: positions sampled from a profile exactly at a cap carry rounding errors of ~1e-15 rad, which
#: the second difference over 0.1 ms steps turns into ~1e-7 rad/s^2 (1e-6 of a 0.1 rad/s^2 cap).
RATE_ROUNDING = 1e-6

#: A `move_linear` target is a rigid transform when det R > 0 and neither max |R^T R - I| nor the largest
#: difference of its last row from [0, 0, 0, 1] exceeds this: poses composed in float64 are rigid to ~1e-15,
#: one rounded to float32 to ~1e-7.
RIGID_TOL = 1e-6


def _finite_tuple(values: object, n: int, name: str, unit: str) -> tuple[float, ...]:
    arr = real_array(values, f"ValidatorConfig.{name} {unit}", (n,))
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"ValidatorConfig.{name} must hold {n} finite numbers {unit}, got {values!r}")
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
        start_tolerance_rad: how far (on any joint) a trajectory waypoint at t = 0 may be from the current
            position [rad]; such a waypoint is reached in zero time, so it must be where the arm already is.
            1e-3 rad lies between what two readings of an arm at rest differ by (a UR's pose repeatability of
            +-0.03 mm at up to a metre from the joints is 3e-5 rad; a trajectory planned from a reading taken
            a moment before it is sent starts there) and what one 2 ms servo cycle at the speed cap moves a
            joint (pi rad/s * 2 ms = 6.3e-3 rad): a jump within the tolerance asks less of the servo than one
            cycle of a capped trajectory.
        max_tcp_speed_m_s, max_tcp_accel_m_s2: caps of `move_linear` [m/s], [m/s^2].
        workspace_min_m, workspace_max_m: (3,) corners of the box in `base` the TCP must stay in [m].
        workspace_step_rad: largest change of any joint between two samples of a joint-space line whose TCP
            is checked against the box [rad] (the module docstring bounds what the TCP does between them).
        clip_speed: lower too-high speed/acceleration arguments to the caps (logged) instead of refusing them.
    """

    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]
    max_joint_speed_rad_s: tuple[float, ...]
    max_joint_accel_rad_s2: float = 4.0
    max_move_step_rad: float = np.pi
    max_waypoint_step_rad: float = 0.2
    start_tolerance_rad: float = 1e-3
    max_tcp_speed_m_s: float = 0.5
    max_tcp_accel_m_s2: float = 2.0
    workspace_min_m: tuple[float, ...] = (-1.5, -1.5, -0.5)
    workspace_max_m: tuple[float, ...] = (1.5, 1.5, 1.5)
    workspace_step_rad: float = 0.005
    clip_speed: bool = field(default=False)

    def __post_init__(self) -> None:
        for name in ("joint_lower_rad", "joint_upper_rad", "max_joint_speed_rad_s"):
            object.__setattr__(self, name, _finite_tuple(getattr(self, name), 6, name, "[rad]"))
        for name in ("workspace_min_m", "workspace_max_m"):
            object.__setattr__(self, name, _finite_tuple(getattr(self, name), 3, name, "[m]"))
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
            "workspace_step_rad",
        )
        for name in (*positive, "start_tolerance_rad"):
            value = real_number(getattr(self, name), f"ValidatorConfig.{name}")
            if not (math.isfinite(value) and (value > 0 or (name == "start_tolerance_rad" and value == 0))):
                raise InvalidInputError(f"ValidatorConfig.{name} must be finite and > 0, got {value!r}")
            object.__setattr__(self, name, value)
        if self.start_tolerance_rad > self.max_waypoint_step_rad:
            raise InvalidInputError(
                "ValidatorConfig: start_tolerance_rad must not exceed max_waypoint_step_rad"
            )
        if min(self.max_joint_speed_rad_s) <= 0:
            raise InvalidInputError("ValidatorConfig.max_joint_speed_rad_s must be > 0")
        if not isinstance(self.clip_speed, (bool, np.bool_)):
            raise InvalidInputError(f"ValidatorConfig.clip_speed must be a bool, got {self.clip_speed!r}")
        object.__setattr__(self, "clip_speed", bool(self.clip_speed))

    @classmethod
    def for_robot(cls, robot, **overrides) -> ValidatorConfig:
        """Limits of a `RobotModel` (joint range and speed from its UR data) plus any field overrides."""
        lower, upper = robot.joint_limits
        base = cls(joint_lower_rad=lower, joint_upper_rad=upper, max_joint_speed_rad_s=robot.max_joint_speed)
        return replace(base, **overrides)


class CommandValidator:
    """Checks commands against a `ValidatorConfig`; `fk_tcp(q) -> T_base_tcp` (q (6,) [rad] -> (4, 4)) enables
    the workspace check for joint commands (linear commands carry their TCP pose)."""

    def __init__(self, config: ValidatorConfig, fk_tcp: Callable[[np.ndarray], np.ndarray] | None = None):
        if not isinstance(config, ValidatorConfig):
            raise InvalidInputError(f"config must be a ValidatorConfig, got {type(config).__name__}")
        if fk_tcp is not None and not callable(fk_tcp):
            raise InvalidInputError(f"fk_tcp must be a callable q -> T_base_tcp or None, got {fk_tcp!r}")
        self.config = config
        self.fk_tcp = fk_tcp
        self._lower = np.array(config.joint_lower_rad)
        self._upper = np.array(config.joint_upper_rad)
        self._vmax = np.array(config.max_joint_speed_rad_s)
        self._box_min = np.array(config.workspace_min_m)
        self._box_max = np.array(config.workspace_max_m)

    # ------------------------------------------------------------------ pieces
    @staticmethod
    def _joint_vector(q: object, what: str, name: str) -> np.ndarray:
        return real_array(q, f"{what}: {name} [rad]", (6,))

    @staticmethod
    def _check_finite(q: np.ndarray, what: str) -> None:
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            j = int(bad[0])
            raise UnsafeCommandError(f"{what}: joint {j} ({JOINT_NAMES[j]}) is {q[j]} (NaN or inf)")

    def _check_limits(self, q: np.ndarray, what: str) -> None:
        outside = np.flatnonzero((q < self._lower) | (q > self._upper))
        if outside.size:
            j = int(outside[0])
            raise UnsafeCommandError(
                f"{what}: joint {j} ({JOINT_NAMES[j]}) target {q[j]:.6g} rad is outside its limits "
                f"[{self._lower[j]:.6g}, {self._upper[j]:.6g}] rad"
            )

    @staticmethod
    def _check_step(q_from: np.ndarray, q_to: np.ndarray, max_step: float, what: str) -> None:
        step = np.abs(q_to - q_from)
        j = int(np.argmax(step))
        if step[j] > max_step:
            raise UnsafeCommandError(
                f"{what}: joint {j} ({JOINT_NAMES[j]}) would move {step[j]:.6g} rad in one step "
                f"(from {q_from[j]:.6g} to {q_to[j]:.6g}); the limit is {max_step:.6g} rad"
            )

    def _check_workspace_point(self, p: np.ndarray, what: str) -> None:
        lo, hi = self._box_min, self._box_max
        if not np.all(np.isfinite(p)):
            raise UnsafeCommandError(f"{what}: the TCP position is not finite ({p.tolist()})")
        outside = np.flatnonzero((p < lo) | (p > hi))
        if outside.size:
            a = int(outside[0])
            raise UnsafeCommandError(
                f"{what}: TCP {'xyz'[a]} = {p[a]:.4f} m is outside the workspace box "
                f"[{lo[a]:.4f}, {hi[a]:.4f}] m (base frame)"
            )

    def _check_workspace_q(self, q: np.ndarray, what: str) -> None:
        if self.fk_tcp is not None:
            T = np.asarray(self.fk_tcp(q), dtype=np.float64)
            if T.shape != (4, 4):
                raise InvalidInputError(f"fk_tcp must return a (4, 4) T_base_tcp, got shape {T.shape}")
            self._check_workspace_point(T[:3, 3], what)

    def _check_workspace_line(self, q_from: np.ndarray, q_to: np.ndarray, what: str) -> None:
        """The TCP at samples of the joint line q_from -> q_to after q_from (which the caller checks), q_to
        included, no joint moving more than `workspace_step_rad` between neighbours."""
        if self.fk_tcp is None:
            return
        n = max(1, math.ceil(float(np.max(np.abs(q_to - q_from))) / self.config.workspace_step_rad))
        for i in range(1, n):
            q = q_from + (i / n) * (q_to - q_from)
            self._check_workspace_q(q, f"{what} ({100.0 * i / n:.0f} % of the way)")
        self._check_workspace_q(q_to, what)

    def _cap(self, value: object, cap: float, name: str, unit: str, what: str) -> float:
        value = real_number(value, f"{what}: {name} [{unit}]")
        if not math.isfinite(value) or value <= 0:
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
        self, q_target: object, speed: object, accel: object, q_current: object
    ) -> JointCommand:
        """Check a `move_joints` from `q_current` (6,) [rad]: the target (6,) [rad] finite and within the
        joint limits, no joint more than `max_move_step_rad` from `q_current`, speed [rad/s] and accel
        [rad/s^2] finite, > 0 and within the caps, and (with `fk_tcp`) the TCP inside the workspace box along
        the joint-space line from `q_current` to the target. Returns the `JointCommand` to send; raises
        `InvalidInputError` (an argument's type or shape) or `UnsafeCommandError` (a limit)."""
        what = "move_joints"
        q = self._joint_vector(q_target, what, "q_target")
        current = self._joint_vector(q_current, what, "q_current")
        real_number(speed, f"{what}: joint speed [rad/s]")
        real_number(accel, f"{what}: joint acceleration [rad/s^2]")
        self._check_configuration(q, current, what)
        speed = self._cap(speed, float(np.min(self._vmax)), "joint speed", "rad/s", what)
        accel = self._cap(accel, self.config.max_joint_accel_rad_s2, "joint acceleration", "rad/s^2", what)
        if self.fk_tcp is not None:
            self._check_workspace_q(current, f"{what} from the current position")
            self._check_workspace_line(current, q, what)
        return JointCommand(q=q, speed_rad_s=speed, accel_rad_s2=accel)

    def _check_configuration(self, q: np.ndarray, current: np.ndarray, what: str) -> None:
        self._check_finite(q, f"{what} target")
        self._check_limits(q, what)
        self._check_finite(current, f"{what} current position")
        self._check_step(current, q, self.config.max_move_step_rad, what)

    def validate_configuration(
        self, q_target: object, q_current: object, what: str = "joint target"
    ) -> np.ndarray:
        """Check a joint configuration (6,) [rad] the arm will move to by some other path (the end of a
        linear move): finite, within limits, at most `max_move_step_rad` from `q_current` (6,) on every joint,
        the TCP inside the workspace there. Returns a float64 copy."""
        q = self._joint_vector(q_target, what, "q_target")
        current = self._joint_vector(q_current, what, "q_current")
        self._check_configuration(q, current, what)
        self._check_workspace_q(q, what)
        return q

    def validate_linear_move(self, T_base_tcp: object, speed: object, accel: object) -> LinearCommand:
        """Check a `move_linear`: the target pose (4, 4) finite, a rigid transform (`RIGID_TOL`), its position
        inside the workspace box (faces included); speed [m/s] and accel [m/s^2] finite, > 0 and within the
        caps. Returns the `LinearCommand` to send."""
        what = "move_linear"
        T = real_array(T_base_tcp, f"{what}: T_base_tcp", (4, 4))
        real_number(speed, f"{what}: TCP speed [m/s]")
        real_number(accel, f"{what}: TCP acceleration [m/s^2]")
        if not np.all(np.isfinite(T)):
            raise UnsafeCommandError(
                f"{what}: T_base_tcp must be a finite (4, 4) transform (it holds NaN/inf)"
            )
        R = T[:3, :3]
        off_rotation = float(np.max(np.abs(R.T @ R - np.eye(3))))
        off_row = float(np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])))
        if max(off_rotation, off_row) > RIGID_TOL or np.linalg.det(R) <= 0:
            raise UnsafeCommandError(
                f"{what}: T_base_tcp is not a rigid transform (max |R^T R - I| = {off_rotation:.3g}, "
                f"det R = {np.linalg.det(R):.6g}, last row off [0, 0, 0, 1] by {off_row:.3g}; "
                f"tolerance {RIGID_TOL:g})"
            )
        self._check_workspace_point(T[:3, 3], what)
        speed = self._cap(speed, self.config.max_tcp_speed_m_s, "TCP speed", "m/s", what)
        accel = self._cap(accel, self.config.max_tcp_accel_m_s2, "TCP acceleration", "m/s^2", what)
        return LinearCommand(T_base_tcp=T, speed_m_s=speed, accel_m_s2=accel)

    def validate_trajectory(self, trajectory: JointTrajectory, q_current: object) -> JointTrajectory:
        """Check a timed trajectory from `q_current` (6,) [rad], where the arm is at rest; it comes to rest at
        the last waypoint. Returns a copy of the trajectory that will be sent.

        The motion's nodes are the start P_0 at time 0 and the waypoints. A waypoint at t = 0 (only the first
        can be) is reached in zero time, so it must be `q_current` within `start_tolerance_rad` on every
        joint, and it is the start P_0 (the backends start from it); otherwise P_0 = `q_current`. With nodes
        P_0 .. P_n at times 0 = t_0 < t_1 < ... < t_n:

        - every waypoint is finite and within the joint limits;
        - steps: |P_k - P_(k-1)| <= `max_waypoint_step_rad` on every joint;
        - speeds: v_k = (P_k - P_(k-1)) / (t_k - t_(k-1)), k = 1..n, within each joint's cap (a segment's
          mean speed: any motion through the nodes reaches at least it);
        - accelerations, from rest and to rest: speed samples 0 at t_0, v_k at the segment midpoints
          (t_(k-1) + t_k) / 2, 0 at t_n; a_k = the change between consecutive samples over the time between
          them, k = 0..n, within `max_joint_accel_rad_s2`. This is twice the second divided difference of
          the positions, the start and the end counted as double nodes (position and zero speed): a_0 =
          2 (P_1 - P_0) / t_1^2, a_n = -2 (P_n - P_(n-1)) / (t_n - t_(n-1))^2. Each a_k is a weighted mean
          (positive weights summing to one) of the acceleration of any twice-differentiable motion through
          the nodes that starts and ends at rest, so a refused trajectory cannot be followed within the cap,
          and samples of a rest-to-rest profile within the cap (`robot.trajectory.joint_trajectory`) pass
          however they are spaced;
        - with `fk_tcp`: the TCP inside the workspace box at every waypoint and along the joint-space line of
          every segment (module docstring).

        Speeds and accelerations may exceed their caps by the relative `RATE_ROUNDING` (1e-6) at most, the
        rounding of the finite differences; steps, limits and the start tolerance are compared exactly.

        Raises `InvalidInputError` for a malformed trajectory or q_current, `UnsafeCommandError` for a limit.
        """
        what = "follow"
        if not isinstance(trajectory, JointTrajectory):
            raise InvalidInputError(f"{what}: expected a JointTrajectory, got {type(trajectory).__name__}")
        try:  # re-checked and copied: the arrays of a JointTrajectory can be changed after it is built
            checked = JointTrajectory(t_s=trajectory.t_s, q=trajectory.q)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{what}: {exc}") from None
        current = self._joint_vector(q_current, what, "q_current")
        self._check_finite(current, f"{what} current position")
        t_way, Q_way = checked.t_s, checked.q
        for k in np.flatnonzero(~np.all(np.isfinite(Q_way), axis=1))[:1]:
            self._check_finite(Q_way[k], f"{what} waypoint {k}")
        cfg = self.config
        if t_way[0] == 0.0:
            gap = np.abs(Q_way[0] - current)
            j = int(np.argmax(gap))
            if gap[j] > cfg.start_tolerance_rad:
                raise UnsafeCommandError(
                    f"{what}: waypoint 0 is at t = 0 but joint {j} ({JOINT_NAMES[j]}) is {gap[j]:.6g} rad "
                    "from the current position (a jump in zero time); a waypoint at t = 0 must be the "
                    f"current position within start_tolerance_rad = {cfg.start_tolerance_rad:.6g} rad"
                )
            P, t = Q_way, t_way  # the first waypoint is the start
        else:
            P, t = np.vstack([current, Q_way]), np.concatenate([[0.0], t_way])
        offset = len(P) - len(Q_way)  # node k is waypoint k - offset; node 0 the current position if 1
        name = ["the current position" if k < offset else f"waypoint {k - offset}" for k in range(len(P))]
        for k in np.flatnonzero(np.any((Q_way < self._lower) | (Q_way > self._upper), axis=1))[:1]:
            self._check_limits(Q_way[k], f"{what} waypoint {k}")
        for k in np.flatnonzero(
            np.max(np.abs(np.diff(P, axis=0)), axis=1, initial=0.0) > cfg.max_waypoint_step_rad
        )[:1]:
            self._check_step(P[k], P[k + 1], cfg.max_waypoint_step_rad, f"{what} {name[k + 1]}")
        if len(P) > 1:
            v = np.diff(P, axis=0) / np.diff(t)[:, None]  # (n, 6) segment mean speeds
            ratio = np.abs(v) / self._vmax
            k, j = (int(i) for i in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
            if ratio[k, j] > 1.0 + RATE_ROUNDING:
                raise UnsafeCommandError(
                    f"{what}: joint {j} ({JOINT_NAMES[j]}) would move at {abs(v[k, j]):.6g} rad/s "
                    f"before {name[k + 1]}; its speed limit is {self._vmax[j]:.6g} rad/s"
                )
            V = np.vstack([np.zeros(6), v, np.zeros(6)])  # at rest at the start and at the end
            t_v = np.concatenate([[0.0], 0.5 * (t[1:] + t[:-1]), [t[-1]]])
            a = np.diff(V, axis=0) / np.diff(t_v)[:, None]  # (n + 1, 6), a[k] at node k
            k, j = (int(i) for i in np.unravel_index(int(np.argmax(np.abs(a))), a.shape))
            if abs(a[k, j]) > cfg.max_joint_accel_rad_s2 * (1.0 + RATE_ROUNDING):
                where = {0: "starting from rest", len(P) - 1: "coming to rest at the last waypoint"}
                raise UnsafeCommandError(
                    f"{what}: joint {j} ({JOINT_NAMES[j]}) would accelerate at {abs(a[k, j]):.6g} rad/s^2 "
                    f"{where.get(k, f'around {name[k]}')} (t = {t[k]:.6g} s); the cap is "
                    f"{cfg.max_joint_accel_rad_s2:.6g} rad/s^2"
                )
        self._check_workspace_q(P[0], f"{what} {'from ' if offset else ''}{name[0]}")
        for k in range(1, len(P)):
            self._check_workspace_line(P[k - 1], P[k], f"{what} {name[k]}")
        return checked
