"""`SimArm`: the simulated UR arm of a `SimWorld` as an `Arm` device.

Every command first goes through the shared `CommandValidator` (the robot layer's, the same one `FakeArm` and
the hardware arm use); what it returns is what is executed, and a refused command raises
`UnsafeCommandError` before anything in the simulation changes. Motions are stepped in the simulation (the
call blocks until the motion is done and the arm has settled), one physics step per control period (2 ms:
500 Hz servo rate):

- `move_joints`: a straight line in joint space with a trapezoidal speed profile; the joint with the largest
  move runs at `speed` / `accel`, the others are scaled to arrive together (as UR's `movej`).
- `move_linear`: a straight line of the TCP in `base` (position linear, orientation along the geodesic) with
  a trapezoidal profile over its length (rotation counts `ROTATION_LENGTH_M` per radian); the closed-form IK
  nearest the previous waypoint gives joint waypoints every `waypoint_dt_s`, which are validated as a timed
  trajectory (joint limits, joint steps, joint speeds and accelerations, workspace) before the arm moves.
- `follow`: a validated timed joint trajectory, interpolated with monotone cubic (PCHIP) splines so it never
  overshoots between waypoints.

Control: MuJoCo position servos (see `sim.robot_scene`) with velocity feed-forward (the target is advanced by
`kv/kp * qd_des`, which makes the servo force `kp (q_des - q) + kv (qd_des - qd)`) and inertial feed-forward
`M(q) qdd_des` as an applied joint force; gravity is compensated per body.

Protective stop, like a UR controller's force limit: every physics step of a motion sums the contact forces
the rest of the world exerts on the robot (arm and gripper) into one net force, the external force a UR
controller estimates at the tool from its joint torques (a grip's squeeze cancels out between the fingers; a
held object adds its weight). The suction cup's lip (`COMPLIANT_GEOMS`) is left out: it stands for the
bellows, which give `compliance_m` (1 cm) under a few newtons on a real cup, while the sim's lip is rigid and
its contact during a planned press carries the servo's full stiffness (155 N on a carton, depalletising seed
0). When the mean over `FORCE_WINDOW_S` exceeds `protective_stop_force_n` (default 150 N, the UR e-Series
default force limit) the arm holds where it is and the command raises the robot
layer's `ProtectiveStopError` (the one the UR adapter raises); every motion command raises it until
`unlock_protective_stop()` (the pendant's "unlock"), or a new `connect()`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import PchipInterpolator

from prompose_grasp.errors import InvalidInputError, UnreachableError, UnsafeCommandError
from prompose_grasp.geometry.se3 import make_T, so3_exp, so3_log
from prompose_grasp.robot.interfaces import (
    Arm,
    JointCommand,
    JointTrajectory,
    LinearCommand,
    ProtectiveStopError,
)
from prompose_grasp.robot.model import RobotModel
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

__all__ = [
    "COMPLIANT_GEOMS",
    "FORCE_WINDOW_S",
    "PROTECTIVE_STOP_FORCE_N",
    "ROTATION_LENGTH_M",
    "SimArm",
    "SimTiming",
    "trapezoid_profile",
]

log = logging.getLogger(__name__)

#: Path length a TCP rotation of one radian counts as in `move_linear` timing [m/rad].
ROTATION_LENGTH_M = 0.2
#: The net external contact force on the robot that stops it [N]: the UR e-Series safety configuration's
#: default force limit (normal mode).
PROTECTIVE_STOP_FORCE_N = 150.0
#: The force is judged as its mean over this long [s]: a controller's force estimate is filtered over a few
#: control cycles, and one 2 ms step of a stiff contact's solver impulse is not a sustained push.
FORCE_WINDOW_S = 0.01
#: Robot geoms whose contacts are not counted: compliant parts modelled rigid (module docstring).
COMPLIANT_GEOMS = ("suction_cup_face",)
#: After a protective stop the arm is held this long before the command raises [s] (a UR's stop brakes the
#: arm within tens of milliseconds).
_STOP_HOLD_S = 0.05


@dataclass(frozen=True)
class SimTiming:
    """Simulated versus wall-clock time spent in an arm's motions.

    Attributes:
        steps: physics steps taken by the arm's commands.
        sim_time_s: simulated time they cover [s].
        wall_time_s: wall-clock time they took [s].
    """

    steps: int
    sim_time_s: float
    wall_time_s: float

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second (> 1: faster than real time)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


def trapezoid_profile(
    length: float, speed: float, accel: float, t_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Distance, speed and acceleration of a trapezoidal (or triangular) profile over `length` at times t_s.

    Args:
        length: distance to cover (>= 0), any unit u.
        speed, accel: cruise speed [u/s] and acceleration [u/s^2], both > 0.
        t_s: (N,) times [s].

    Returns:
        s (N,), s' (N,), s'' (N,) at t_s (clamped to [0, duration]), and the duration [s].
    """
    t = np.clip(np.asarray(t_s, dtype=np.float64), 0.0, None)
    if length <= 0.0:
        z = np.zeros_like(t)
        return z, z, z, 0.0
    t_acc = speed / accel
    if accel * t_acc**2 >= length:  # never reaches cruise speed: a triangle
        t_acc = math.sqrt(length / accel)
        speed = accel * t_acc
    t_cruise = (length - accel * t_acc**2) / speed
    duration = 2.0 * t_acc + t_cruise
    t = np.minimum(t, duration)
    s = np.empty_like(t)
    v = np.empty_like(t)
    a = np.empty_like(t)
    up = t < t_acc
    down = t > t_acc + t_cruise
    mid = ~(up | down)
    s[up], v[up], a[up] = 0.5 * accel * t[up] ** 2, accel * t[up], accel
    tm = t[mid] - t_acc
    s[mid], v[mid], a[mid] = 0.5 * accel * t_acc**2 + speed * tm, speed, 0.0
    td = duration - t[down]
    s[down], v[down], a[down] = length - 0.5 * accel * td**2, accel * td, -accel
    end = t >= duration
    s[end], v[end], a[end] = length, 0.0, 0.0
    return s, v, a, duration


#: A trajectory whose first waypoint is this close to the arm (measured or set-point) starts there [rad]: the
#: servo error at rest (loaded, or pressing a suction cup on a face) is below it.
_START_TOL_RAD = 0.005


class SimArm(Arm):
    """The arm of a `SimWorld` built with a robot (`sim.robot_scene.add_robot` or a scene file's `robot`).

    Args:
        world: the `SimWorld`; its physics is stepped by the motion commands.
        robot_model: the arm's `RobotModel` (IK for `move_linear`, the tcp offset of `tcp_pose`); the world's
            own (tcp = the gripper's TCP) if None. It must be the same UR model as the world's arm.
        validator: the command validator; `CommandValidator(ValidatorConfig.for_robot(robot_model),
            fk_tcp=robot_model.fk_tcp)` if None.
        waypoint_dt_s: spacing of the IK waypoints of `move_linear` [s].
        settle_speed_rad_s: a motion is done when every joint is slower than this after the profile ends.
        max_settle_s: longest wait for that after the profile [s].
        protective_stop_force_n: the net external contact force that stops the arm (module docstring) [N],
            or None for no force limit.

    Attributes:
        protective_stopped: the arm is in a protective stop (motion commands raise `ProtectiveStopError`).
        max_external_force_n: the largest windowed net external force seen during motions so far [N].
    """

    def __init__(
        self,
        world,
        robot_model: RobotModel | None = None,
        validator: CommandValidator | None = None,
        waypoint_dt_s: float = 0.016,
        settle_speed_rad_s: float = 2e-3,
        max_settle_s: float = 0.5,
        protective_stop_force_n: float | None = PROTECTIVE_STOP_FORCE_N,
    ):
        info = getattr(world, "robot", None)
        if info is None:
            raise InvalidInputError("SimArm needs a world with a robot (scene `robot:` or sim.add_robot)")
        robot = info.robot if robot_model is None else robot_model
        if robot.name != info.name:
            raise InvalidInputError(f"robot_model is {robot.name!r} but the world's arm is {info.name!r}")
        if not (math.isfinite(waypoint_dt_s) and waypoint_dt_s >= world.model.opt.timestep):
            raise InvalidInputError(f"waypoint_dt_s must be >= the time step, got {waypoint_dt_s}")
        limit = protective_stop_force_n
        if limit is not None and not (math.isfinite(float(limit)) and float(limit) > 0):
            raise InvalidInputError(f"protective_stop_force_n must be None or > 0 N, got {limit!r}")
        self.world = world
        self.info = info
        self.robot = robot
        self.validator = validator or CommandValidator(ValidatorConfig.for_robot(robot), fk_tcp=robot.fk_tcp)
        self.waypoint_dt_s = float(waypoint_dt_s)
        self.settle_speed_rad_s = float(settle_speed_rad_s)
        self.max_settle_s = float(max_settle_s)
        self._stop = threading.Event()
        self._steps = 0
        self._wall_s = 0.0
        m = world.model
        self._dt = float(m.opt.timestep)
        self._ff_gain = info.kv / info.kp  # velocity feed-forward as a target advance [s]
        self._vec = np.zeros(m.nv)
        self._res = np.zeros(m.nv)
        self.protective_stop_force_n = None if limit is None else float(limit)
        self.protective_stopped = False
        self.max_external_force_n = 0.0
        root = m.body_rootid[info.flange_body]  # the arm's base body under the world; its subtree: the robot
        self._robot_geom = np.asarray(m.body_rootid[m.geom_bodyid] == root)  # (ngeom,) bool
        self._counted = np.ones(m.ngeom, dtype=bool)  # (ngeom,) bool: contacts of the geom count
        for name in COMPLIANT_GEOMS:
            g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
            if g >= 0:
                self._counted[g] = False
        self._forces: deque[float] = deque(maxlen=max(1, round(FORCE_WINDOW_S / self._dt)))
        self._f6 = np.zeros(6)
        self._contact_note = ""
        self._q_cmd: np.ndarray | None = None  # (6,) the set-point last commanded, before feed-forward [rad]
        self._guard_n: float | None = None  # a guarded move's force limit [N] while one runs
        self._guard_tripped = False

    # ------------------------------------------------------------------ device
    def connect(self) -> None:
        super().connect()
        self._stop.clear()
        self.protective_stopped = False

    def unlock_protective_stop(self) -> None:
        """Clear a protective stop (a person found the cause; the pendant's "unlock")."""
        self._require()
        self.protective_stopped = False

    def external_force(self) -> tuple[float, str]:
        """The net contact force the world exerts on the robot now [N], and the contact that pushes hardest
        ("robot geom <- other geom"; "" without contact)."""
        m, d = self.world.model, self.world.data
        n = int(d.ncon)
        if n == 0:
            return 0.0, ""
        geoms = np.asarray(d.contact.geom[:n])
        on_robot = self._robot_geom[geoms]
        # robot against the rest (not self-contact), compliant parts left out
        hits = np.flatnonzero((on_robot[:, 0] != on_robot[:, 1]) & self._counted[geoms].all(axis=1))
        if hits.size == 0:
            return 0.0, ""
        total = np.zeros(3)
        worst, note = -1.0, ""
        frames = np.asarray(d.contact.frame[:n])
        for i in hits:
            mujoco.mj_contactForce(m, d, int(i), self._f6)
            f_world = frames[i].reshape(3, 3).T @ self._f6[:3]  # geom1 on geom2, in the world frame
            g_robot, g_other = (geoms[i, 1], geoms[i, 0]) if on_robot[i, 1] else (geoms[i, 0], geoms[i, 1])
            f_robot = f_world if on_robot[i, 1] else -f_world
            total += f_robot
            if self._f6[0] > worst:
                worst = float(self._f6[0])
                note = f"{_geom_name(m, g_robot)} <- {_geom_name(m, g_other)}"
        return float(np.linalg.norm(total)), note

    # ------------------------------------------------------------------ state
    def joint_positions(self) -> np.ndarray:
        """(6,) float64 measured joint positions [rad]."""
        self._require()
        return self.world.data.qpos[self.info.qpos_adr].copy()

    def joint_velocities(self) -> np.ndarray:
        """(6,) float64 measured joint speeds [rad/s]."""
        self._require()
        return self.world.data.qvel[self.info.dof_adr].copy()

    def joint_targets(self) -> np.ndarray:
        """(6,) float64 servo set-points [rad] (where the arm is told to be)."""
        return self.world.data.ctrl[self.info.actuator_ids].copy()

    def commanded_joint_positions(self) -> np.ndarray:
        """(6,) float64 the joint set-point the motion commands gave the servos last [rad], without the
        velocity feed-forward advance `joint_targets` includes (the servo targets before any command)."""
        return self.joint_targets() if self._q_cmd is None else self._q_cmd.copy()

    def T_world_flange(self) -> np.ndarray:
        """(4, 4) flange pose in the world from the simulation state [m]."""
        m, d = self.world.model, self.world.data
        mujoco.mj_kinematics(m, d)  # body poses of the current qpos (mj_step leaves them one step behind)
        b = self.info.flange_body
        return make_T(d.xmat[b].reshape(3, 3), d.xpos[b])

    def tcp_pose(self) -> np.ndarray:
        """(4, 4) T_base_tcp from the simulated flange pose (not from the joint readings)."""
        self._require()
        return self.info.T_base_world @ self.T_world_flange() @ self.robot.T_flange_tcp

    def timing(self) -> SimTiming:
        """Simulated and wall-clock time spent in this arm's motions so far."""
        return SimTiming(self._steps, self._steps * self._dt, self._wall_s)

    # ------------------------------------------------------------------ commands
    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        self._require()
        self._require_unlocked("move_joints")
        q0 = self.joint_targets()
        command = self.validator.validate_joint_move(q, speed, accel, q_current=q0)
        delta = command.q - q0
        dist = float(np.max(np.abs(delta)))
        _, _, _, duration = trapezoid_profile(dist, command.speed_rad_s, command.accel_rad_s2, np.zeros(1))
        t = self._step_times(duration)
        s, sd, sdd, _ = trapezoid_profile(dist, command.speed_rad_s, command.accel_rad_s2, t)
        unit = delta / dist if dist > 0 else np.zeros(6)
        self._execute(q0 + np.outer(s, unit), np.outer(sd, unit), np.outer(sdd, unit), command.q)
        return command

    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        self._require()
        self._require_unlocked("move_linear")
        command = self.validator.validate_linear_move(T_base_tcp, speed, accel)
        q0 = self.joint_targets()
        T0, T1 = self.robot.fk_tcp(q0), command.T_base_tcp
        dp = T1[:3, 3] - T0[:3, 3]
        w = so3_log(T0[:3, :3].T @ T1[:3, :3])
        length = max(float(np.linalg.norm(dp)), float(np.linalg.norm(w)) * ROTATION_LENGTH_M)
        if length < 1e-9:
            return command
        # Like a UR controller's moveL, the line is timed slower when the joint motion it needs would exceed
        # the joint limits (near a wrist singularity a slow TCP line needs fast joints): up to three times
        # at half the speed and a quarter of the acceleration; the validator has the last word each time.
        speed, accel = command.speed_m_s, command.accel_m_s2
        for attempt in range(4):
            _, _, _, duration = trapezoid_profile(length, speed, accel, np.zeros(1))
            n = max(1, math.ceil(duration / self.waypoint_dt_s))
            t_way = np.linspace(duration / n, duration, n)
            s, _, _, _ = trapezoid_profile(length, speed, accel, t_way)
            q_way = np.empty((n, 6))
            q_prev = q0
            for k, frac in enumerate(s / length):
                T = make_T(T0[:3, :3] @ so3_exp(frac * w), T0[:3, 3] + frac * dp)
                result = self.robot.ik(T, q_seed=q_prev, frame="tcp")
                if not result.success:
                    raise UnreachableError(
                        f"move_linear: the line leaves the reachable space at {100 * frac:.0f} % of its "
                        f"length (TCP at {np.round(T[:3, 3], 4).tolist()} m in base): {result.message}"
                    )
                q_way[k] = q_prev = result.q
            try:
                sent = self.validator.validate_trajectory(JointTrajectory(t_s=t_way, q=q_way), q0)
            except UnsafeCommandError as exc:
                if attempt == 3 or not any(k in str(exc) for k in ("accelerate", "would move at")):
                    raise
                speed, accel = 0.5 * speed, 0.25 * accel
                continue
            break
        self._run_trajectory(sent, q0)
        return command

    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        self._require()
        self._require_unlocked("follow")
        q0 = self.joint_targets()
        q_meas = self.joint_positions()
        q_first = np.asarray(trajectory.q, dtype=np.float64)[0]
        if min(np.max(np.abs(q_first - q_meas)), np.max(np.abs(q_first - q0))) < _START_TOL_RAD:
            # A trajectory planned from where the arm is (a real controller starts trajectories from the
            # actual joint positions): its first waypoint differs from the set-point by the servo error (a
            # cup pressed on a face, a load, settling), which would be a jump in the first 2 ms. At rest
            # between moves, re-anchor the set-point on the first waypoint.
            q0 = q_first.copy()
            self._apply(q0, np.zeros(6), np.zeros(6))
        sent = self.validator.validate_trajectory(trajectory, q0)
        self._run_trajectory(sent, q0)
        return sent

    @property
    def senses_contact(self) -> bool:
        return True

    def move_linear_until_contact(
        self, T_base_tcp: ArrayLike, speed: float, accel: float, max_force_n: float
    ) -> bool:
        """`move_linear`, stopped at the first physics step whose net external force on the robot exceeds
        `max_force_n` [N] (below `protective_stop_force_n`): the servos then hold the measured joints, as a
        controller's guarded move stops within a few milliseconds of the touch. True when the line was
        completed, False when it stopped on contact."""
        limit = self.contact_force_limit(max_force_n)
        if self.protective_stop_force_n is not None and limit >= self.protective_stop_force_n:
            raise InvalidInputError(
                f"max_force_n {limit:g} N must be under the protective stop's "
                f"{self.protective_stop_force_n:g} N"
            )
        self._guard_n, self._guard_tripped = limit, False
        try:
            self.move_linear(T_base_tcp, speed, accel)
        finally:
            self._guard_n = None
        return not self._guard_tripped

    def stop(self) -> None:
        """Decelerate the running motion to a stop at the validator's joint acceleration cap (thread-safe)."""
        self._require()
        self._stop.set()

    def servo(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> None:
        """One control period of a set-point stream: servo to `q` (6,) [rad] with speed `qd` [rad/s] and
        acceleration `qdd` [rad/s^2] feed-forward (as the motion commands do), and step the physics once.

        For replaying recorded set-points (`sim.recording.replay_episode`). A recording can be edited or
        damaged, so each set-point is validated as a configuration (finite, within the joint limits, the TCP
        in the workspace), and no joint's set-point may move more in one step than 3 x its speed cap allows:
        the replay interpolates 20 Hz set-points of speed-capped moves with a monotone cubic (PCHIP), whose
        slope is at most 3 x the slope between its knots (Fritsch-Carlson). Raises `UnsafeCommandError` for
        a set-point that breaks these, before it is applied, and `ProtectiveStopError` as the motion commands
        do."""
        self._require()
        self._require_unlocked("servo")
        q_now = self.commanded_joint_positions()  # the last set-point, without the feed-forward advance
        q = self.validator.validate_configuration(q, q_now, what="servo set-point")
        qd, qdd = (np.asarray(v, dtype=np.float64).reshape(6) for v in (qd, qdd))
        step_cap = 3.0 * np.asarray(self.validator.config.max_joint_speed_rad_s) * self._dt
        jump = np.abs(q - q_now)
        if not (np.all(np.isfinite(qd)) and np.all(np.isfinite(qdd))):
            raise UnsafeCommandError("servo: the speed or acceleration feed-forward is not finite")
        if np.any(jump > step_cap):
            j = int(np.argmax(jump - step_cap))
            raise UnsafeCommandError(
                f"servo: joint {j} set-point jumps {jump[j]:.4f} rad in one {self._dt * 1e3:.0f} ms step "
                f"(at most {step_cap[j]:.4f} rad: 3 x its speed cap)"
            )
        self._apply(q, qd, qdd)
        fault = self._step()
        self._steps += 1
        if fault is not None:
            self._protective_stop(fault)

    # ------------------------------------------------------------------ execution
    def _require_unlocked(self, what: str) -> None:
        if self.protective_stopped:
            raise ProtectiveStopError(
                f"{what}: the arm is in a protective stop; find the cause, then unlock_protective_stop()"
            )

    def _step(self) -> str | None:
        """One physics step; why the arm must stop now (the windowed external force over the limit), else
        None."""
        self.world.step(1)
        if self.protective_stop_force_n is None:
            return None
        force, note = self.external_force()
        if note:
            self._contact_note = note
        self._forces.append(force)
        mean = sum(self._forces) / len(self._forces)
        self.max_external_force_n = max(self.max_external_force_n, mean)
        if len(self._forces) == self._forces.maxlen and mean > self.protective_stop_force_n:
            return (
                f"protective stop: {mean:.0f} N of contact force on the robot over "
                f"{1e3 * FORCE_WINDOW_S:g} ms (limit {self.protective_stop_force_n:g} N; hardest contact "
                f"{self._contact_note})"
            )
        return None

    def _protective_stop(self, why: str) -> None:
        """Hold the arm where it is (servos at the measured joints, no feed-forward), mark it stopped and
        raise `ProtectiveStopError`."""
        d, info = self.world.data, self.info
        d.ctrl[info.actuator_ids] = d.qpos[info.qpos_adr]
        self._q_cmd = d.qpos[info.qpos_adr].copy()
        d.qfrc_applied[info.dof_adr] = 0.0
        n = round(_STOP_HOLD_S / self._dt)
        self.world.step(n)
        self._steps += n
        self._forces.clear()
        self.protective_stopped = True
        q = np.round(d.qpos[info.qpos_adr], 4).tolist()
        log.warning("SimArm: %s; held at %s rad", why, q)
        raise ProtectiveStopError(f"{why}; the arm holds at {q} rad")

    def _step_times(self, duration_s: float) -> np.ndarray:
        n = max(1, math.ceil(duration_s / self._dt - 1e-9))
        return np.arange(1, n + 1) * self._dt

    def _run_trajectory(self, trajectory: JointTrajectory, q0: np.ndarray) -> None:
        t_knots, q_knots = trajectory.t_s, trajectory.q
        if t_knots[0] > 0.0:  # the motion starts at the current set-point
            t_knots = np.concatenate([[0.0], t_knots])
            q_knots = np.vstack([q0, q_knots])
        if len(t_knots) < 2:
            self._execute(q_knots[-1][None], np.zeros((1, 6)), np.zeros((1, 6)), q_knots[-1])
            return
        spline = PchipInterpolator(t_knots, q_knots, axis=0)
        t = t_knots[0] + self._step_times(t_knots[-1] - t_knots[0])
        t = np.minimum(t, t_knots[-1])
        self._execute(spline(t), spline(t, 1), spline(t, 2), q_knots[-1])

    def _apply(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        m, d, info = self.world.model, self.world.data, self.info
        self._q_cmd = np.array(q, dtype=np.float64)
        d.ctrl[info.actuator_ids] = q + self._ff_gain * qd
        self._vec[info.dof_adr] = qdd
        mujoco.mj_mulM(m, d, self._res, self._vec)  # inertia of the arm (and what it carries rigidly)
        d.qfrc_applied[info.dof_adr] = self._res[info.dof_adr]

    def _execute(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, q_final: np.ndarray) -> None:
        """Step the servo set-points (N, 6) through the physics, then hold `q_final` until the arm settles."""
        self._stop.clear()
        self._forces.clear()
        world, d, info = self.world, self.world.data, self.info
        wall0 = time.perf_counter()
        steps = 0
        stopped = False
        fault = None
        for k in range(len(q)):
            if self._stop.is_set():
                stopped = True
                q_final = self._decelerate(q[k - 1] if k else q[0], qd[k - 1] if k else qd[0])
                break
            self._apply(q[k], qd[k], qdd[k])
            fault = self._step()
            steps += 1
            if fault is not None:
                break
            if self._guard_n is not None and self._forces[-1] > self._guard_n:
                # a guarded move's touch: hold the measured joints (no feed-forward), as a controller's
                # stop on contact does; the settling below holds them
                self._guard_tripped = True
                q_final = d.qpos[info.qpos_adr].copy()
                log.info("SimArm: guarded move stopped on contact (%.0f N; %s)", self._forces[-1],
                         self._contact_note)  # fmt: skip
                break
        if fault is None:
            d.ctrl[info.actuator_ids] = q_final
            self._q_cmd = np.array(q_final, dtype=np.float64)
            d.qfrc_applied[info.dof_adr] = 0.0
            max_steps = round(self.max_settle_s / self._dt)
            for _ in range(max_steps):
                if np.max(np.abs(d.qvel[info.dof_adr])) < self.settle_speed_rad_s:
                    break
                fault = self._step()
                steps += 1
                if fault is not None:
                    break
        self._steps += steps
        self._wall_s += time.perf_counter() - wall0
        if not world.is_finite():
            raise InvalidInputError("the simulation diverged (non-finite state) during an arm motion")
        if fault is not None:
            self._protective_stop(fault)
        if stopped:
            log.info("SimArm: motion stopped at %s rad", np.round(q_final, 4).tolist())

    def _decelerate(self, q0: np.ndarray, v0: np.ndarray) -> np.ndarray:
        """Ramp every joint's set-point speed from v0 to zero at the acceleration cap; returns the end q."""
        a_max = self.validator.config.max_joint_accel_rad_s2
        t_stop = np.abs(v0) / a_max
        t = self._step_times(float(np.max(t_stop)))
        tt = np.minimum(t[:, None], t_stop[None, :])
        sign = np.sign(v0)
        q = q0 + v0 * tt - 0.5 * sign * a_max * tt**2
        qd = v0 - sign * a_max * tt
        qdd = np.where(t[:, None] < t_stop[None, :], -sign * a_max, 0.0)
        for k in range(len(t)):
            self._apply(q[k], qd[k], qdd[k])
            self._steps += 1
            fault = self._step()
            if fault is not None:
                self._protective_stop(fault)
        self._stop.clear()
        return q[-1]


def _geom_name(model, geom_id: int) -> str:
    """A geom's name, else its body's (unnamed geoms of a mesh decomposition)."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, int(geom_id))
    if name:
        return name
    body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[geom_id]))
    return f"a geom of {body or 'the world'}"
