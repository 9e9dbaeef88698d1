"""Timed joint trajectories: synchronised trapezoidal joint moves, and straight TCP lines tracked by mink.

Both return a `JointTrajectory` sampled at the control period, within the arm's joint speed limits, ready for
the shared `CommandValidator` and any `Arm.follow`. Nothing here talks to an arm.

- `joint_trajectory`: every joint follows the same normalised trapezoidal velocity profile, so the motion is
  a straight line in joint space that starts and ends at rest; its duration is set by the most limiting joint.
- `linear_trajectory`: the TCP follows a straight line (position) and a slerp (orientation) under a
  trapezoidal path-speed profile. Each control step solves one mink differential-IK step towards the moving
  target with the joint velocity limits of the arm (`mink.VelocityLimit`), the joint limits, and, when a
  support plane is given, collision avoidance between the arm's capsules and the plane. If the arm cannot
  keep up (a singularity, a limit), the result deviates from the line: that deviation is measured and a
  trajectory that leaves `path_tolerance_m` is refused with `UnreachableError` rather than returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from prompose_grasp.errors import InvalidInputError, UnreachableError
from prompose_grasp.geometry.se3 import as_transform, rotation_angle
from prompose_grasp.robot.interfaces import JointTrajectory
from prompose_grasp.robot.model import Frame, RobotModel

__all__ = ["LinearTrajectory", "joint_trajectory", "linear_trajectory", "trapezoid_profile"]

#: Control period of the UR controller (500 Hz on e-Series) [s]; the default sampling of trajectories.
UR_CONTROL_PERIOD_S = 0.002


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise InvalidInputError(f"{name} must be a finite number > 0, got {value}")
    return value


def trapezoid_profile(
    distance: float, max_speed: float, max_accel: float, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """A rest-to-rest trapezoidal (or, when max_speed is never reached, triangular) profile covering
    `distance` with |ds/dt| <= max_speed and |d2s/dt2| <= max_accel, sampled every dt_s.

    Returns:
        (t, s): (K,) float64 sample times dt_s, 2 dt_s, ... whose last entry is the end time T exactly (so the
        last interval may be shorter than dt_s), and (K,) the exact profile s(t) there, s[-1] = distance.
        Both are empty for a zero distance.
    """
    distance, v, a = float(distance), float(max_speed), float(max_accel)
    if distance <= 0.0:
        return np.zeros(0), np.zeros(0)
    t_acc = v / a
    if a * t_acc**2 >= distance:
        t_acc = math.sqrt(distance / a)
        v = a * t_acc
        t_total = 2.0 * t_acc
    else:
        t_total = 2.0 * t_acc + (distance - a * t_acc**2) / v
    t = np.arange(1, math.ceil(t_total / dt_s - 1e-9) + 1) * dt_s
    t[-1] = t_total
    s = np.where(
        t < t_acc,
        0.5 * a * t**2,
        np.where(
            t <= t_total - t_acc,
            0.5 * a * t_acc**2 + v * (t - t_acc),
            distance - 0.5 * a * (t_total - t) ** 2,
        ),
    )
    return t, np.minimum(s, distance)


def joint_trajectory(
    q_start: ArrayLike,
    q_goal: ArrayLike,
    max_speed_rad_s: ArrayLike,
    max_accel_rad_s2: float,
    dt_s: float = UR_CONTROL_PERIOD_S,
) -> JointTrajectory:
    """A synchronised rest-to-rest joint move from `q_start` to `q_goal`.

    Args:
        q_start, q_goal: (6,) joint positions [rad].
        max_speed_rad_s: (6,) per-joint speed caps [rad/s] (or a scalar for all joints).
        max_accel_rad_s2: joint acceleration cap [rad/s^2].
        dt_s: sample period [s].
    Returns:
        JointTrajectory with samples at dt_s, 2 dt_s, ... (the start itself is not repeated); for a zero move,
        a single sample at dt_s holding q_goal.
    """
    q0 = np.asarray(q_start, dtype=np.float64)
    q1 = np.asarray(q_goal, dtype=np.float64)
    if q0.shape != (6,) or q1.shape != (6,) or not (np.all(np.isfinite(q0)) and np.all(np.isfinite(q1))):
        raise InvalidInputError(f"q_start and q_goal must be finite (6,) [rad], got {q0.shape}, {q1.shape}")
    vmax = np.broadcast_to(np.asarray(max_speed_rad_s, dtype=np.float64), (6,))
    if not np.all(np.isfinite(vmax)) or np.any(vmax <= 0):
        raise InvalidInputError(f"max_speed_rad_s must be finite and > 0, got {vmax}")
    amax = _positive(max_accel_rad_s2, "max_accel_rad_s2")
    dt_s = _positive(dt_s, "dt_s")
    delta = q1 - q0
    # One normalised profile s in [0, 1] for all joints; joint j moves delta_j * s, so its speed cap on s is
    # vmax_j / |delta_j|: the tightest joint sets the profile.
    moving = np.abs(delta) > 0
    if not np.any(moving):
        return JointTrajectory(t_s=np.array([dt_s]), q=q1[None, :])
    s_speed = float(np.min(vmax[moving] / np.abs(delta[moving])))
    s_accel = float(amax / np.max(np.abs(delta)))
    t, s = trapezoid_profile(1.0, s_speed, s_accel, dt_s)
    return JointTrajectory(t_s=t, q=q0 + s[:, None] * delta)


@dataclass(frozen=True)
class LinearTrajectory:
    """A straight TCP line turned into joint motion.

    Attributes:
        trajectory: the joint trajectory (samples at the control period).
        max_path_deviation_m: largest distance of the TCP from the commanded point at the same time [m].
        final_position_error_m, final_rotation_error_rad: where the last sample's TCP is, against the goal.
    """

    trajectory: JointTrajectory
    max_path_deviation_m: float
    final_position_error_m: float
    final_rotation_error_rad: float


def linear_trajectory(
    robot: RobotModel,
    q_start: ArrayLike,
    T_base_goal: ArrayLike,
    speed_m_s: float,
    accel_m_s2: float,
    dt_s: float = UR_CONTROL_PERIOD_S,
    frame: Frame = "tcp",
    support_plane_z_m: float | None = None,
    path_tolerance_m: float = 0.005,
    goal_tolerance_m: float = 1e-4,
    goal_tolerance_rad: float = 1e-3,
    max_settle_steps: int = 500,
) -> LinearTrajectory:
    """Track a straight line from the current `frame` pose to `T_base_goal` with mink differential IK.

    Args:
        robot: the arm model (its joint limits and speed limits are enforced).
        q_start: (6,) current joint positions [rad].
        T_base_goal: (4, 4) goal pose of `frame` in `base`.
        speed_m_s, accel_m_s2: path speed and acceleration caps of the TCP [m/s, m/s^2]; the rotation is
            slerped on the same path parameter.
        dt_s: control period [s].
        frame: "tcp" or "flange".
        support_plane_z_m: when given, the arm's capsules keep clear of the plane z = this in `base`.
        path_tolerance_m: the largest accepted deviation of the TCP from the commanded line [m].
        goal_tolerance_m, goal_tolerance_rad: how close the final sample must come to the goal.
        max_settle_steps: extra control steps allowed at the goal to converge.
    Raises:
        UnreachableError: the TCP leaves the line by more than path_tolerance_m, or misses the goal.
    """
    import mink

    q0 = robot.check_q(q_start, "q_start")
    T_goal = as_transform(T_base_goal, "T_base_goal")
    speed, accel, dt_s = (
        _positive(x, n) for x, n in ((speed_m_s, "speed_m_s"), (accel_m_s2, "accel_m_s2"), (dt_s, "dt_s"))
    )
    if frame not in ("tcp", "flange"):
        raise InvalidInputError(f"frame must be 'tcp' or 'flange', got {frame!r}")
    T_frame_flange = np.linalg.inv(robot.T_flange_tcp) if frame == "tcp" else np.eye(4)
    T_start = robot.fk_frame(q0, frame)

    # Path parameter: the translation length, or for a pure rotation an equivalent length so that the
    # rotation takes as long as moving its angle times 0.1 m (a hand-sized lever arm) would.
    length = float(np.linalg.norm(T_goal[:3, 3] - T_start[:3, 3]))
    angle = rotation_angle(T_start[:3, :3], T_goal[:3, :3])
    path_length = max(length, 0.1 * angle)
    # Path samples s in (0, 1]; mink takes one control step per sample.
    s = trapezoid_profile(path_length, speed, accel, dt_s)[1] / path_length if path_length > 0 else np.ones(1)
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T_start[:3, :3], T_goal[:3, :3]])))
    targets_R = slerp(s).as_matrix()
    targets_p = T_start[:3, 3] + s[:, None] * (T_goal[:3, 3] - T_start[:3, 3])

    model = robot.mj_model_with_plane
    configuration = mink.Configuration(model)
    configuration.update(q0)
    task = mink.FrameTask("flange", "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-6)
    limits: list = [
        mink.ConfigurationLimit(model),
        mink.VelocityLimit(model, dict(zip(robot.joint_names, robot.max_joint_speed))),
    ]
    if support_plane_z_m is not None:
        import mujoco

        plane = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "support_plane")
        model.geom_pos[plane, 2] = float(support_plane_z_m)
        limits.append(
            mink.CollisionAvoidanceLimit(
                model,
                geom_pairs=[(list(robot.plane_checked_geoms), ["support_plane"])],
                minimum_distance_from_collisions=0.005,
                collision_detection_distance=0.05,
            )
        )

    def step_towards(R: np.ndarray, p: np.ndarray) -> np.ndarray:
        T_target = np.eye(4)
        T_target[:3, :3], T_target[:3, 3] = R, p
        task.set_target(mink.SE3.from_matrix(T_target @ T_frame_flange))
        # Aim to close the remaining error within one step; VelocityLimit caps what is actually commanded.
        velocity = mink.solve_ik(configuration, [task], dt_s, "daqp", damping=1e-9, limits=limits)
        configuration.integrate_inplace(velocity, dt_s)
        return configuration.q.copy()

    Q, deviation = [], 0.0
    for R, p in zip(targets_R, targets_p):
        q = step_towards(R, p)
        Q.append(q)
        deviation = max(deviation, float(np.linalg.norm(robot.fk_frame(q, frame)[:3, 3] - p)))
        if deviation > path_tolerance_m:
            raise UnreachableError(
                f"linear move: the TCP left the straight line by {deviation * 1e3:.1f} mm "
                f"(tolerance {path_tolerance_m * 1e3:.1f} mm) at {len(Q)} of {len(s)} samples; "
                "a joint limit, speed limit or singularity is in the way"
            )
    for _ in range(max_settle_steps):
        T_now = robot.fk_frame(Q[-1], frame)
        pos = float(np.linalg.norm(T_now[:3, 3] - T_goal[:3, 3]))
        rot = rotation_angle(T_now[:3, :3], T_goal[:3, :3])
        if pos <= goal_tolerance_m and rot <= goal_tolerance_rad:
            break
        Q.append(step_towards(T_goal[:3, :3], T_goal[:3, 3]))
    T_now = robot.fk_frame(Q[-1], frame)
    pos = float(np.linalg.norm(T_now[:3, 3] - T_goal[:3, 3]))
    rot = rotation_angle(T_now[:3, :3], T_goal[:3, :3])
    if pos > goal_tolerance_m or rot > goal_tolerance_rad:
        raise UnreachableError(
            f"linear move: the goal was not reached ({pos * 1e3:.2f} mm, {math.degrees(rot):.3f} deg away "
            f"after {max_settle_steps} settling steps)"
        )
    t = np.arange(1, len(Q) + 1) * dt_s
    return LinearTrajectory(JointTrajectory(t_s=t, q=np.array(Q)), deviation, pos, rot)
