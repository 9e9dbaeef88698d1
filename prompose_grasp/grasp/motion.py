"""Pick-and-place motion: pre-grasp -> grasp -> lift -> transfer -> pre-place -> place -> retreat, as joint
space segments within the limits, collision-checked along the path.

Straight tcp moves (approach, lift, descend, retreat) are joint paths through closed-form IK waypoints on the
line, each the solution nearest the previous (the same branch); free moves (to the pre-grasp, the transfer)
are straight lines in joint space, with a detour through points `safe_height_m` above both ends when the
direct line collides.

Collision checking along a segment. Between two checked samples every point of the arm, the gripper and the
held object moves less than `resolution_m`: a joint step dq moves a point at most sum_j |dq_j| r_j, where r_j
bounds the distance of any moving point from joint j's axis (the DH offsets beyond joint j, the tcp offset,
the gripper's size and the held object's diagonal; `reach_bounds`). With `resolution_m` = 5 mm no point can
step over a 1 cm obstacle between samples. At each sample the arm's capsules, the gripper's parts (the sim's
primitives at the segment's opening) and the held object's box (shrunk by `contact_margin_m`, attached to the
tcp) are checked against the scene with fcl; the target is an obstacle until it is grasped (and the gripper
may touch it only at the grasp: the approach checks the fingers against it with the pads open).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from enum import Enum

import fcl
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, NoFeasibleMotion
from prompose_grasp.geometry.distance import segment_box_distance
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import invert_T
from prompose_grasp.grasp.batch_ik import ik_nearest_batch, link_frames_batch
from prompose_grasp.grasp.grippers import ParallelJawGeometry, SuctionCupGeometry, as_gripper
from prompose_grasp.grasp.place import PlacePose, PlaceTarget
from prompose_grasp.grasp.scene import CollisionScene, Hit
from prompose_grasp.grasp.types import Grasp, ObjectModel
from prompose_grasp.robot.interfaces import JointTrajectory
from prompose_grasp.robot.model import RobotModel
from prompose_grasp.robot.trajectory import joint_trajectory

__all__ = [
    "GripperAction",
    "MotionConfig",
    "MotionSegment",
    "PickPlaceMotion",
    "check_path",
    "free_move",
    "held_acceleration",
    "place_support_fixture",
    "plan_pick_place",
    "reach_bounds",
    "timed_held_trajectory",
    "timed_trajectory",
]


@dataclass(frozen=True)
class MotionConfig:
    """Settings of motion planning.

    Attributes:
        resolution_m: largest motion of any point between two collision-checked samples [m].
        line_step_m: spacing of IK waypoints on straight tcp moves [m].
        safe_height_m: height of the detour above the higher end of a blocked free move [m].
        contact_margin_m: the held object's box is shrunk by this (it rests on its support at the start) [m].
        speed_scale: fraction of the arm's joint speed limits used to time the segments.
        max_accel_rad_s2: joint acceleration used to time the segments [rad/s^2].
        suction_held_accel_m_s2: with a suction cup, the segments that carry the object (lift, transfer,
            descend) are slowed down uniformly until the acceleration of the held box's centre stays below
            this [m/s^2]. A vacuum cup holds sideways by lip friction only: at its rated payload
            (`SuctionCupGeometry.max_payload_kg`, safety factor 2 on the pull, F = 2 m g) the lip holds
            m a_h <= mu (F - m (g + a_v)), i.e. an acceleration of mu g / sqrt(1 + mu^2) = 6.1 m/s^2 (mu 0.8)
            in the worst direction; this is half of that (the servos overshoot the planned profile). The
            joint timing alone gave the held carton 7 m/s^2 and more (docs/benchmarks.md, depalletising).
    """

    resolution_m: float = 0.005
    line_step_m: float = 0.02
    safe_height_m: float = 0.15
    contact_margin_m: float = 0.003
    speed_scale: float = 0.5
    max_accel_rad_s2: float = 2.0
    suction_held_accel_m_s2: float = 3.0

    def __post_init__(self) -> None:
        names = ("resolution_m", "line_step_m", "speed_scale", "max_accel_rad_s2", "suction_held_accel_m_s2")
        for name in names:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"MotionConfig.{name} must be finite and > 0, got {v!r}")


class GripperAction(Enum):
    """What the gripper does when a segment ends: nothing, close on the object (jaws close, vacuum on), or
    open to let it go."""

    NONE = "none"
    CLOSE = "close"
    OPEN = "open"


@dataclass(frozen=True, eq=False)
class MotionSegment:
    """One segment of the motion.

    Attributes:
        name: "to_pregrasp", "approach", "lift", "transfer", "descend", "retreat".
        kind: "line" (straight tcp move through the waypoints) or "joint" (straight in joint space).
        waypoints: (K, 6) joint configurations [rad], start and end included.
        path: (M, 6) the samples that were collision-checked [rad], start and end included.
        trajectory: the waypoints timed as synchronised rest-to-rest joint moves at the control period.
        holding: the object is held during the segment.
        opening_m: the jaw opening during the segment [m].
        gripper_after: what the gripper does once the arm has followed the segment (CLOSE after the
            approach, OPEN after the descent to the place pose).
    """

    name: str
    kind: str
    waypoints: np.ndarray
    path: np.ndarray
    trajectory: JointTrajectory
    holding: bool
    opening_m: float
    gripper_after: GripperAction = GripperAction.NONE


@dataclass(frozen=True, eq=False)
class PickPlaceMotion:
    """The segments in execution order, and the poses they connect."""

    segments: tuple[MotionSegment, ...]
    grasp: Grasp
    place: PlacePose

    def segment(self, name: str) -> MotionSegment:
        for s in self.segments:
            if s.name == name:
                return s
        raise KeyError(name)


def reach_bounds(robot: RobotModel, tool_extent_m: float) -> np.ndarray:
    """(6,) r_j [m]: an upper bound on the distance from joint j's axis of any point moved by joint j.

    Sum of the |a_i| and |d_i| of the DH rows beyond joint j (the chain from the joint to the flange), plus
    `tool_extent_m` (the farthest point of the tool and the held object from the flange) and the largest link
    capsule radius."""
    spec = robot.spec
    a, d = np.abs(spec.a_m), np.abs(spec.d_m)
    radius = max(spec.capsule_radius_m)
    return np.array([float(np.sum(a[j:]) + np.sum(d[j + 1 :])) + tool_extent_m + radius for j in range(6)])


def _samples(q0: np.ndarray, q1: np.ndarray, r: np.ndarray, resolution_m: float) -> np.ndarray:
    """(M, 6) samples of the joint line q0 -> q1, including both, close enough that no point moves more than
    `resolution_m` between neighbours."""
    sweep = float(np.abs(q1 - q0) @ r)
    m = max(1, math.ceil(sweep / resolution_m))
    s = np.linspace(0.0, 1.0, m + 1)[:, None]
    return q0 + s * (q1 - q0)


class _Mover:
    """The gripper's parts (and a held box) as parts moving with the flange, for `arm_hits_batch`."""

    def __init__(
        self, gripper, opening_m: float, held: ObjectModel | None, T_tcp_obj: np.ndarray | None, margin
    ):
        T_flange_tcp = gripper.T_flange_tcp
        self.parts: list[tuple[str, fcl.CollisionGeometry, np.ndarray, np.ndarray, str]] = []
        for part in gripper.parts(opening_m):  # a suction cup ignores the opening
            if part.shape == "box":
                half = np.asarray(part.size_m, dtype=np.float64)
                geom = fcl.Box(*(2.0 * half))
            else:
                r, h = part.size_m[0], part.size_m[1]
                half = np.array([r, r, h])
                geom = fcl.Cylinder(r, 2.0 * h)
            self.parts.append((part.name, geom, T_flange_tcp @ part.T_tcp_part, half, part.shape))
        if held is not None and T_tcp_obj is not None:
            half = np.maximum(held.pose.size / 2.0 - margin, 1e-4)
            self.parts.append(("held object", fcl.Box(*(2.0 * half)), T_flange_tcp @ T_tcp_obj, half, "box"))


def check_path(
    robot: RobotModel,
    scene: CollisionScene,
    Q: np.ndarray,
    gripper: ParallelJawGeometry | SuctionCupGeometry,
    opening_m: float,
    include_target: bool,
    held: ObjectModel | None = None,
    T_tcp_obj: np.ndarray | None = None,
    config: MotionConfig | None = None,
) -> tuple[np.ndarray, Hit | None]:
    """Collision-check the joint path through waypoints Q (K, 6) at the resolution of `config`.

    Returns:
        (samples (M, 6) checked [rad], the first `Hit` or None). Samples outside the joint limits are reported
        as Hit("limits", ...).
    """
    cfg = config or MotionConfig()
    Q = np.asarray(Q, dtype=np.float64)
    lower, upper = robot.joint_limits
    tool = float(np.linalg.norm(gripper.T_flange_tcp[:3, 3])) + 0.1  # tcp offset + the gripper's own size
    if held is not None:
        tool += float(np.linalg.norm(held.pose.size))
    r = reach_bounds(robot, tool)
    mover = _Mover(gripper, opening_m, held, T_tcp_obj, cfg.contact_margin_m)
    samples = [Q[0][None]]
    for q0, q1 in itertools.pairwise(Q):
        samples.append(_samples(q0, q1, r, cfg.resolution_m)[1:])
    S = np.vstack(samples)
    out = np.flatnonzero(np.any((S < lower - 1e-12) | (S > upper + 1e-12), axis=1))
    first_out = int(out[0]) if out.size else len(S)
    # All samples up to the first one outside the limits in one batched query; the first hit along the path.
    hits = scene.arm_hits_batch(robot, S[:first_out], include_target=include_target, extra=mover.parts)
    if held is not None and T_tcp_obj is not None:
        own = _held_arm_hits(robot, S[:first_out], gripper.T_flange_tcp @ T_tcp_obj, held, cfg)
        hits = [h if h is not None else o for h, o in zip(hits, own)]
    for hit in hits:
        if hit is not None:
            return S, hit
    if out.size:
        return S, Hit("limits", f"joint limits at {np.round(S[first_out], 3).tolist()}")
    return S, None


def _arm_segments(robot, frames: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """The link capsules at N configurations (link frames (N, 8, 4, 4)): (link names (C,), ends p0, p1
    (N, C, 3) in `base` [m], radii (C,))."""
    names, p0, p1, radius = [], [], [], []
    for i, link in enumerate(robot.description.links):
        for cap in link.capsules:
            F = frames[:, i]
            names.append(link.name)
            p0.append(F[:, :3, :3] @ np.asarray(cap.p0, dtype=np.float64) + F[:, :3, 3])
            p1.append(F[:, :3, :3] @ np.asarray(cap.p1, dtype=np.float64) + F[:, :3, 3])
            radius.append(float(cap.radius_m))
    return names, np.stack(p0, axis=1), np.stack(p1, axis=1), np.array(radius)


def _held_arm_hits(
    robot, Q: np.ndarray, T_flange_obj: np.ndarray, held: ObjectModel, cfg: MotionConfig
) -> list[Hit | None]:
    """The held box (shrunk by `contact_margin_m`) against the arm's own link capsules at each configuration
    of Q (N, 6): a carried carton swung into the upper arm is knocked off the cup (the scene check sees only
    the scene). Links already touching the box at Q[0] (the grasp: the capsules are a conservative envelope,
    and whatever touches there rides along rigidly, e.g. the wrist) are not counted."""
    n = len(Q)
    if n == 0:
        return []
    frames = link_frames_batch(robot.spec, Q)
    names, p0, p1, radius = _arm_segments(robot, frames)
    T_obj = frames[:, 7] @ np.asarray(T_flange_obj, dtype=np.float64)  # (N, 4, 4)
    half = np.maximum(held.pose.size / 2.0 - cfg.contact_margin_m, 1e-4)
    C = len(names)
    d = segment_box_distance(
        p0.reshape(-1, 3),
        p1.reshape(-1, 3),
        np.repeat(T_obj[:, :3, 3], C, axis=0),
        np.repeat(T_obj[:, :3, :3], C, axis=0),
        np.tile(half, (n * C, 1)),
    ).reshape(n, C)
    touching = d < radius[None, :]
    touching[:, touching[0]] = False
    out: list[Hit | None] = [None] * n
    for i in np.flatnonzero(np.any(touching, axis=1)):
        out[i] = Hit("arm", f"held object against the arm's {names[int(np.argmax(touching[i]))]}")
    return out


def _line(robot, T_from, T_to, q_start, T_tcp_flange, step_m) -> np.ndarray | None:
    """Joint waypoints along the straight tcp line T_from -> T_to (same orientation, or interpolated
    linearly in position only when they share it), each nearest the previous; None when IK fails."""
    dist = float(np.linalg.norm(T_to[:3, 3] - T_from[:3, 3]))
    k = max(1, math.ceil(dist / step_m))
    lower, upper = robot.joint_limits
    Q = [np.asarray(q_start, dtype=np.float64)]
    for s in np.linspace(0.0, 1.0, k + 1)[1:]:
        T = T_to.copy()
        T[:3, 3] = T_from[:3, 3] + s * (T_to[:3, 3] - T_from[:3, 3])
        q, ok, _ = ik_nearest_batch(robot.spec, (T @ T_tcp_flange)[None], Q[-1], lower, upper)
        if not ok[0] or np.linalg.norm(q[0] - Q[-1]) > 1.0:  # a branch jump, not a small line step
            return None
        Q.append(q[0])
    return np.array(Q)


def held_acceleration(
    robot: RobotModel, traj: JointTrajectory, T_flange_point: np.ndarray, q_start: ArrayLike
) -> np.ndarray:
    """(M,) acceleration [m/s^2] at each sample of a trajectory (sampled at a constant period, starting at
    rest at `q_start` (6,) one period before its first sample, ending at rest) of a point fixed to the flange
    (`T_flange_point` (4, 4), e.g. a held box's centre), by central differences of the point's path."""
    t = np.asarray(traj.t_s, dtype=np.float64)
    Q = np.asarray(traj.q, dtype=np.float64)
    dt = float(t[1] - t[0]) if len(t) > 1 else float(t[0])
    q0 = np.asarray(q_start, dtype=np.float64)[None]
    F = link_frames_batch(robot.spec, np.vstack([q0, q0, Q, Q[-1:]]))[:, 7]
    p = (F @ np.asarray(T_flange_point, dtype=np.float64))[:, :3, 3]
    a = (p[2:] - 2.0 * p[1:-1] + p[:-2]) / dt**2
    return np.linalg.norm(a, axis=1)


def timed_held_trajectory(
    robot: RobotModel, W: np.ndarray, cfg: MotionConfig, T_flange_point: np.ndarray, max_accel_m_s2: float
) -> JointTrajectory:
    """`timed_trajectory`, slowed down uniformly (speeds / k, accelerations / k^2: the same path, every
    acceleration, tangential and centripetal, / k^2) until the acceleration of the point `T_flange_point`
    (4, 4) in the flange frame stays below `max_accel_m_s2` [m/s^2]."""
    traj = timed_trajectory(robot, W, cfg)
    for _ in range(4):  # the sampled profile scales as 1/k^2 only up to the control period's rounding
        peak = float(np.max(held_acceleration(robot, traj, T_flange_point, W[0]), initial=0.0))
        if peak <= max_accel_m_s2:
            return traj
        k = math.sqrt(peak / max_accel_m_s2) * 1.02  # 2 %: a little under the cap after resampling
        cfg = dataclasses.replace(
            cfg, speed_scale=cfg.speed_scale / k, max_accel_rad_s2=cfg.max_accel_rad_s2 / k**2
        )
        traj = timed_trajectory(robot, W, cfg)
    return traj


def timed_trajectory(robot: RobotModel, W: np.ndarray, cfg: MotionConfig) -> JointTrajectory:
    """Joint waypoints W (K, 6) -> one trajectory of synchronised, velocity-limited joint segments."""
    vmax = robot.max_joint_speed * cfg.speed_scale
    t_all, q_all, t0 = [], [], 0.0
    for q0, q1 in itertools.pairwise(W):
        seg = joint_trajectory(q0, q1, vmax, cfg.max_accel_rad_s2)
        t_all.append(seg.t_s + t0)
        q_all.append(seg.q)
        t0 = float(t_all[-1][-1])
    if not t_all:
        return JointTrajectory(t_s=np.array([0.002]), q=W[-1:])
    return JointTrajectory(t_s=np.concatenate(t_all), q=np.vstack(q_all))


#: How far a surface place target's body reaches beyond its usable surface [m]: a conveyor's frame and side
#: guides stand up to 2 cm outside its belt (`SceneBuilder.add_conveyor`); a little more for a real one.
PLACE_RIM_M = 0.04
#: How deep below its surface a surface place target's body is taken to be [m] (a conveyor's frame and
#: legs, a table's top and legs: solid enough that nothing carried passes under the surface nearby).
PLACE_BODY_DEPTH_M = 0.5
#: A surface whose footprint comes this close to the base origin is one the arm stands on or beside [m]: the
#: base link's radius (UR16e 0.09 m) and a margin.
_BASE_CLEARANCE_M = 0.15


def place_support_fixture(
    target: PlaceTarget, rim_m: float = PLACE_RIM_M, depth_m: float = PLACE_BODY_DEPTH_M
) -> ObjectModel | None:
    """The body of a surface place target (a conveyor, a table) below its surface, as a fixture box for the
    collision scene of the moves that carry the object: its footprint grown by `rim_m`, from the surface
    down `depth_m`. The camera that found the object may not see the place at all (the depalletising cell's
    overhead camera does not see the conveyor); without it a transfer's joint line that sags on its way down
    to the pre-place swept the carried carton through the conveyor's side guide. None for a bin (its walls
    are part of the target), a pallet (its deck is a layer below anything carried onto it), and a surface the
    arm stands on or beside (its base origin within the footprint grown by `_BASE_CLEARANCE_M`: a table the
    arm is mounted on, which the support plane already stands for)."""
    if target.kind != "surface":
        return None
    T = np.asarray(target.T_base_surface, dtype=np.float64)
    base_local = T[:3, :3].T @ -T[:3, 3]  # the base origin in the surface frame
    if np.all(np.abs(base_local[:2]) <= target.half_extents_xy_m + rim_m + _BASE_CLEARANCE_M):
        return None
    size = np.array([*(2.0 * (target.half_extents_xy_m + rim_m)), depth_m])
    # The box frame: the surface's axes; its centre half the depth below the surface.
    centre = T[:3, 3] - 0.5 * depth_m * T[:3, 2]
    return ObjectModel("place support", Pose9D(T[:3, :3], centre, size), kind="fixture")


def plan_pick_place(
    robot: RobotModel,
    grasp: Grasp,
    place: PlacePose,
    obj: ObjectModel,
    scene_pick: CollisionScene,
    scene_place: CollisionScene | None = None,
    gripper: ParallelJawGeometry | SuctionCupGeometry | str = "parallel_jaw",
    q_start: ArrayLike | None = None,
    config: MotionConfig | None = None,
) -> PickPlaceMotion:
    """The collision-checked segments of one pick and place.

    Args:
        robot: the arm; grasp: from `plan_grasps` (with `q`); place: from `plan_place`.
        obj: the object picked (as estimated; its box is carried).
        scene_pick: the scene with the object as its target (the object is an obstacle until grasped).
        scene_place: the scene without the object (for the moves while it is held); `scene_pick` without
            its target if None.
        gripper: the gripper.
        q_start: (6,) the arm's configuration now [rad]; the segment "to_pregrasp" is added when given.
        config: `MotionConfig`.

    Raises:
        NoFeasibleMotion: a segment has no IK along its line or collides (its name and what it hit).
    """
    cfg = config or MotionConfig()
    grip = as_gripper(gripper)
    if grasp.q is None:
        raise InvalidInputError("grasp.q is None: plan the grasp with plan_grasps (it sets q)")
    T_tcp_flange = invert_T(grip.T_flange_tcp)
    T_tcp_obj = invert_T(grasp.T_base_tcp) @ obj.pose.to_matrix()
    held_scene = scene_place or scene_pick
    opening = grasp.opening_m
    segments: list[MotionSegment] = []
    is_suction = isinstance(grip, SuctionCupGeometry)

    def add(name, kind, W, holding, include_target, scene, gripper_after=GripperAction.NONE):
        if W is None:
            raise NoFeasibleMotion(name, "no IK solution along the straight tcp line on the same branch")
        held = obj if holding else None
        S, hit = check_path(
            robot,
            scene,
            W,
            grip,
            opening,
            include_target=include_target,
            held=held,
            T_tcp_obj=T_tcp_obj,
            config=cfg,
        )
        if hit is not None:
            raise NoFeasibleMotion(name, f"{hit.reason}: {hit.name}")
        if holding and is_suction:  # the cup holds by lip friction: the carried box's centre is kept gentle
            T_flange_obj = grip.T_flange_tcp @ T_tcp_obj
            traj = timed_held_trajectory(robot, W, cfg, T_flange_obj, cfg.suction_held_accel_m_s2)
        else:
            traj = timed_trajectory(robot, W, cfg)
        segments.append(MotionSegment(name, kind, W, S, traj, holding, opening, gripper_after))
        return W[-1]

    # Approach: from the pre-grasp down the line to the grasp (walked backwards from the grasp's q, so the
    # branch is the grasp's).
    W_back = _line(robot, grasp.T_base_tcp, grasp.T_base_pregrasp, grasp.q, T_tcp_flange, cfg.line_step_m)
    W_approach = None if W_back is None else W_back[::-1]
    if q_start is not None and W_approach is not None:
        q0 = robot.check_q(q_start, "q_start")
        W_to = free_move(robot, scene_pick, q0, W_approach[0], gripper=grip, opening_m=opening, config=cfg)
        add("to_pregrasp", "joint", W_to, False, True, scene_pick)
    # The suction cup ends in contact with the target's face; the jaws stay clear of it until they close.
    add("approach", "line", W_approach, False, not is_suction, scene_pick, GripperAction.CLOSE)
    q = add(
        "lift",
        "line",
        _line(robot, grasp.T_base_tcp, grasp.T_base_retreat, grasp.q, T_tcp_flange, cfg.line_step_m),
        True,
        False,
        held_scene,
    )
    W_pre = _line(robot, place.T_base_tcp, place.T_base_preplace, place.q, T_tcp_flange, cfg.line_step_m)
    if W_pre is None:
        raise NoFeasibleMotion("descend", "no IK solution along the straight line above the place pose")
    W_transfer = free_move(
        robot,
        held_scene,
        q,
        W_pre[-1],
        gripper=grip,
        opening_m=opening,
        held=obj,
        T_tcp_obj=T_tcp_obj,
        config=cfg,
    )
    add("transfer", "joint", W_transfer, True, False, held_scene)
    add("descend", "line", W_pre[::-1], True, False, held_scene, GripperAction.OPEN)
    W_ret = _line(robot, place.T_base_tcp, place.T_base_retreat, place.q, T_tcp_flange, cfg.line_step_m)
    add("retreat", "line", W_ret, False, False, held_scene)
    return PickPlaceMotion(tuple(segments), grasp, place)


def free_move(
    robot: RobotModel,
    scene: CollisionScene,
    q0: ArrayLike,
    q1: ArrayLike,
    *,
    gripper: ParallelJawGeometry | SuctionCupGeometry,
    opening_m: float,
    held: ObjectModel | None = None,
    T_tcp_obj: np.ndarray | None = None,
    config: MotionConfig | None = None,
) -> np.ndarray:
    """A free move: the joint line q0 -> q1 (6,) [rad], or, when it collides, a detour: straight up from q0, a
    joint line across, straight down to q1, at 1, 2, 3 or 4 x `safe_height_m` above the higher end (the first
    free; carrying an object, 0, 1/3 and 2/3 x first). Returns the joint waypoints (K, 6) [rad].

    Args:
        gripper, opening_m: the gripper and its opening during the move [m].
        held: the object carried (`T_tcp_obj` (4, 4) its pose in the tcp frame), or None: then the target
            is an obstacle.
        config: `MotionConfig`.

    Raises:
        NoFeasibleMotion: the line collides and no detour is free and reachable ("transfer" when carrying,
            else "to_pregrasp").
    """
    if held is not None and T_tcp_obj is None:
        raise InvalidInputError("free_move: a held object needs its pose in the tcp frame (T_tcp_obj)")
    cfg = config or MotionConfig()
    holding = held is not None
    T_tcp_flange = invert_T(gripper.T_flange_tcp)
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)

    def first_hit(W: np.ndarray) -> Hit | None:  # the path W (K, 6) through the scene
        return check_path(
            robot,
            scene,
            W,
            gripper,
            opening_m,
            include_target=not holding,
            held=held,
            T_tcp_obj=T_tcp_obj,
            config=cfg,
        )[1]

    W = np.array([q0, q1])
    hit = first_hit(W)
    if hit is None:
        return W
    T0 = robot.fk(q0) @ gripper.T_flange_tcp
    T1 = robot.fk(q1) @ gripper.T_flange_tcp
    up = np.array([0.0, 0.0, 1.0]) if scene.support is None else np.asarray(scene.support.normal)
    h0, h1 = float(T0[:3, 3] @ up), float(T1[:3, 3] @ up)
    # Carrying an object, lower detours first (at the higher end's own height, then a third and two thirds
    # of `safe_height_m` above it): from a pallet's far corner 15 cm above the pre-place is out of reach.
    for k in (0.0, 1 / 3, 2 / 3, 1, 2, 3, 4) if holding else (1, 2, 3, 4):
        top = max(h0, h1) + k * cfg.safe_height_m
        A, B = T0.copy(), T1.copy()
        A[:3, 3] += (top - h0) * up
        B[:3, 3] += (top - h1) * up
        up0 = _line(robot, T0, A, q0, T_tcp_flange, cfg.line_step_m)
        down1 = _line(robot, T1, B, q1, T_tcp_flange, cfg.line_step_m)
        if up0 is None or down1 is None:
            break  # higher is out of reach too
        W = np.vstack([up0, down1[::-1]])
        if first_hit(W) is None:
            return W
    name = "transfer" if holding else "to_pregrasp"
    raise NoFeasibleMotion(
        name, f"blocked ({hit.reason}: {hit.name}); no detour above it is free and reachable"
    )
