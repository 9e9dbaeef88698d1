"""`plan_grasps`: candidates -> analytic filters -> batched IK -> fcl gripper check -> ranking -> arm check.

Stages, each on the survivors of the one before (a candidate counts once, for the first check it fails):

1. synthesis (`synthesis.py`): box, antipodal and rim candidates (`parallel_jaw.py`), suction candidates
   (`suction.py`), and for a target whose box is wider than the stroke, section grasps on its seen surface
   (`surface.py`); capped at `max_candidates` (best
   quality first); generators already mark "stroke" (too wide for the jaws), "payload" (too heavy for the
   cup) and "suction_not_flat" (the cup would not seal on the mesh);
2. "support": the gripper, swept from the pre-grasp to the grasp, dips below the support plane plus
   `support_clearance_m` (exact for the gripper's tcp-aligned hull boxes; numpy on all candidates at once);
3. "ik": no closed-form solution within the joint limits (`batch_ik.ik_nearest_batch`, all candidates in one
   numpy pass; the branch nearest `q_seed`);
4. "collision_object" / "collision_fixture" / "collision_points" / "collision_target" / "collision_seen":
   the swept gripper hull boxes (palm, each finger at the opening; or stem and cup) touch another object, a
   fixture, the voxelised observed points, (mesh grasps only) the target away from the contacts, or (parallel
   jaw) hold the target's own seen surface (`ObjectModel.surface_points`) where its fitted box or mesh is not;
   one fcl broadphase query for all candidates;
5. ranking by score = quality - `joint_distance_weight` x joint distance from the seed [rad];
6. "ik_approach": the pre-grasp or the retreat pose has no solution on the grasp's branch (within 1 rad of
   it); "arm_collision": the arm's link capsules touch the scene at the `arm_branches` in-limit branches
   of the grasp nearest the seed. This runs in rank order, in chunks, until `max_grasps` grasps
   passed (over all of them with `exhaustive`).

Raises `NoFeasibleGrasp` with the per-reason counts when nothing passes.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, NoFeasibleGrasp
from prompose_grasp.geometry.se3 import invert_T
from prompose_grasp.grasp.batch_ik import fk_reaches, ik_nearest_batch
from prompose_grasp.grasp.candidates import Candidates
from prompose_grasp.grasp.grippers import ParallelJawGeometry, SuctionCupGeometry, as_gripper
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.self_filter import robot_self_capsules
from prompose_grasp.grasp.synthesis import generate_candidates
from prompose_grasp.grasp.types import Grasp, GraspConfig, GraspPlan, ObjectModel, Plane
from prompose_grasp.robot.kinematics import fk_batch
from prompose_grasp.robot.model import RobotModel

__all__ = ["build_scene", "gripper_hulls", "plan_grasps"]

log = logging.getLogger(__name__)

#: Two IK solutions are on the same branch, for the pre-grasp and retreat poses, within this joint distance
#: [rad]: a 10 cm tcp move changes no joint by more than ~0.5 rad away from singularities.
_SAME_BRANCH_RAD = 1.0
#: ... so a longer line (a lift above a tall object) is followed in steps of at most this [m].
_BRANCH_STEP_M = 0.10
#: The target's seen surface is where the object certainly is, and a fitted box or prior mesh can leave parts
#: of it out (an ear, a spout, a top higher than the fit's): a parallel-jaw candidate whose hull boxes, swept
#: along the approach and shrunk by `_SEEN_TOLERANCE_M` (the seen surface's depth noise at 1 m, after its
#: median filter, is 1-2 mm), hold at least `_SEEN_HIT_POINTS` of its points would strike the object on the
#: way in. One or two points may be strays; a protrusion of a centimetre holds tens at the 2-3 mm spacing of
#: a surface seen from 0.8 m. At most `_SEEN_MAX_POINTS`, evenly picked, are tested.
_SEEN_TOLERANCE_M = 0.003
_SEEN_HIT_POINTS = 3
_SEEN_MAX_POINTS = 1024


def _config(config: object) -> GraspConfig:
    if config is None:
        return GraspConfig()
    if not isinstance(config, GraspConfig):
        raise InvalidInputError(f"config must be a GraspConfig or None, got {type(config).__name__}")
    return config


def gripper_hulls(
    gripper: ParallelJawGeometry | SuctionCupGeometry, opening_m: np.ndarray, sweep_m: float
) -> tuple[list[tuple[float, float, float]], np.ndarray]:
    """The gripper's hull boxes swept `sweep_m` back along the approach, per candidate, in the tcp frame.

    Returns:
        (halves, centres): K half extents (x, y, z) [m], and (N, K, 3) box centres in the tcp frame [m]
        (the finger boxes move with `opening_m` (N,)).
    """
    hulls = gripper.hull_boxes(0.0)  # the fingers at the tcp; they are moved to `opening_m` below
    halves, centres = [], []
    for name, (lo, hi) in hulls.items():
        lo, hi = lo.copy(), hi.copy()
        lo[2] -= sweep_m  # swept back along -z (towards the pre-grasp)
        half = (hi - lo) / 2.0
        c = np.broadcast_to((hi + lo) / 2.0, (len(opening_m), 3)).copy()
        if name == "finger_left":
            c[:, 1] += opening_m / 2.0
        elif name == "finger_right":
            c[:, 1] -= opening_m / 2.0
        halves.append((float(half[0]), float(half[1]), float(half[2])))
        centres.append(c)
    return halves, np.stack(centres, axis=1)


def _lowest_heights(
    T: np.ndarray, halves: list[tuple[float, float, float]], centres_tcp: np.ndarray, support: Plane
) -> np.ndarray:
    """(N,) lowest height above the support of any hull box corner (exact for boxes) [m]."""
    n = support.normal
    # Height of a box = height of its centre - sum_k |n . axis_k| half_k; the axes are the tcp axes.
    n_tcp = n @ T[:, :3, :3]  # (N, 3): the normal's components along the tcp axes
    axes_dot = np.abs(n_tcp)
    base_h = support.height(T[:, :3, 3])
    low = np.full(T.shape[0], np.inf)
    for k, half in enumerate(halves):
        c = centres_tcp[:, k, :]
        h = base_h + np.einsum("ij,ij->i", n_tcp, c) - axes_dot @ np.asarray(half)
        low = np.minimum(low, h)
    return low


def _lift_off_support(
    cands: Candidates,
    which: np.ndarray,
    deficit_m: np.ndarray,
    support: Plane,
    gripper: ParallelJawGeometry,
    config: GraspConfig,
) -> np.ndarray:
    """Move the parallel-jaw candidates `which` (N,) back along their approach until the gripper clears the
    support by `support_clearance_m` (`deficit_m` (N,): how far short of that each one is), where the pads
    still hold both contacts; returns (N,) which were moved (`cands` is changed in place).

    An object lower than a pad is held with the fingertips just above the support, the contacts on the
    pads' lower part: a knife lying flat, 15 mm high, under a 30 mm pad. A candidate keeps its contacts
    when each lies at least `fingertip_contact_margin_m` inside the pad's lower edge after the move; the
    move must come from an approach within 60 degrees of straight down (a side approach moved back does not
    rise). The quality loses the depth term's share of the pad that no longer presses on the object.
    """
    out = np.zeros(len(cands), dtype=bool)
    idx = np.flatnonzero(which)
    if idx.size == 0 or config.fingertip_contact_margin_m < 0:
        return out
    T = cands.T_base_tcp[idx]
    a = T[:, :3, 2]
    rise = -(a @ np.asarray(support.normal))  # height gained per metre moved back along the approach
    steep = rise >= 0.5
    back = np.where(steep, deficit_m[idx] / np.maximum(rise, 1e-9), np.inf)
    # contacts' depth along the approach below the moved tcp, against the pad's half length
    along = np.einsum("nkj,nj->nk", cands.contacts[idx] - T[:, None, :3, 3], a)
    half_pad = 0.5 * gripper.pad_size_m[2]
    held = np.all(along + back[:, None] <= half_pad - config.fingertip_contact_margin_m, axis=1)
    ok = steep & held
    moved = idx[ok]
    cands.T_base_tcp[moved, :3, 3] -= back[ok, None] * a[ok]
    cands.quality[moved] -= 0.2 * np.minimum(1.0, back[ok] / gripper.pad_size_m[2])
    out[moved] = True
    return out


def build_scene(
    target: ObjectModel,
    robot: RobotModel,
    gripper: ParallelJawGeometry | SuctionCupGeometry | str = "parallel_jaw",
    obstacles: Sequence[ObjectModel] = (),
    support: Plane | None = None,
    points_base: ArrayLike | None = None,
    q_robot: ArrayLike | None = None,
    config: GraspConfig | None = None,
) -> CollisionScene:
    """The `CollisionScene` `plan_grasps` builds: points cropped to the arm's reach + 0.3 m, without the robot
    itself at `q_robot` (the configuration it had when the points were taken), the target's and the support's
    points, and the points already explained by obstacles."""
    cfg = _config(config)
    grip = as_gripper(gripper)
    if not isinstance(robot, RobotModel):
        raise InvalidInputError(f"robot must be a RobotModel (load_robot(...)), got {type(robot).__name__}")
    if isinstance(obstacles, ObjectModel) or not isinstance(obstacles, Sequence | set | frozenset):
        raise InvalidInputError(
            f"obstacles must be a list of ObjectModel values (base frame), got {type(obstacles).__name__}"
        )
    caps = [] if q_robot is None else robot_self_capsules(robot, grip, robot.check_q(q_robot, "q_robot"))
    return CollisionScene(
        obstacles,
        support,
        points_base,
        target,
        voxel_size_m=cfg.voxel_size_m,
        target_margin_m=cfg.target_margin_m,
        support_band_m=cfg.support_band_m,
        crop_radius_m=robot.spec.reach_m + 0.3,
        robot_capsules=caps,
    )


def plan_grasps(
    target: ObjectModel,
    robot: RobotModel,
    gripper: ParallelJawGeometry | SuctionCupGeometry | str = "parallel_jaw",
    obstacles: Sequence[ObjectModel] = (),
    support: Plane | None = None,
    points_base: ArrayLike | None = None,
    q_seed: ArrayLike | None = None,
    config: GraspConfig | None = None,
    scene: CollisionScene | None = None,
) -> GraspPlan:
    """Feasible grasps of `target`, best first.

    Args:
        target: the object to pick (`ObjectModel` in `base`: 9-DoF box, optional mesh, family, mass).
        robot: the arm (`load_robot(name, tcp_offset=gripper.T_flange_tcp)`); IK uses the gripper's tcp.
        gripper: "parallel_jaw", "suction", or a geometry.
        obstacles: other objects and fixtures in `base`.
        support: the plane the target stands on, in `base`.
        points_base: (N, 3) observed points in `base` [m] (the target's and the support's are dropped).
        q_seed: (6,) current joint configuration [rad]; zeros if None. The points are taken to be observed
            with the arm there (its own points are removed; see `build_scene`).
        config: `GraspConfig`.
        scene: a prebuilt `CollisionScene` for this target (then obstacles/support/points are not used).

    Returns:
        `GraspPlan` with `grasps` best first and per-reason rejection counts.

    Raises:
        NoFeasibleGrasp: every candidate was rejected (its `rejected` holds the counts).
        InvalidInputError: malformed inputs.
    """
    t0 = time.perf_counter()
    cfg = _config(config)
    grip = as_gripper(gripper)
    if not isinstance(target, ObjectModel):
        raise InvalidInputError(f"target must be an ObjectModel in base, got {type(target).__name__}")
    if not isinstance(robot, RobotModel):
        raise InvalidInputError(f"robot must be a RobotModel (load_robot(...)), got {type(robot).__name__}")
    seed = np.zeros(6) if q_seed is None else robot.check_q(q_seed, "q_seed")
    if scene is not None and not isinstance(scene, CollisionScene):
        raise InvalidInputError(f"scene must be a CollisionScene (build_scene), got {type(scene).__name__}")
    if scene is None:
        scene = build_scene(target, robot, grip, obstacles, support, points_base, seed, cfg)
    support = scene.support
    timings: dict[str, float] = {"scene": (time.perf_counter() - t0) * 1e3}

    t = time.perf_counter()
    cands = generate_candidates(target, grip, cfg, support)
    n = len(cands)
    timings["generate"] = (time.perf_counter() - t) * 1e3
    rejected: Counter[str] = Counter()
    status = np.array(cands.pre_rejected, dtype=object) if n else np.zeros(0, dtype=object)

    # Support plane (analytic, exact for the hull boxes).
    t = time.perf_counter()
    halves, centres_tcp = gripper_hulls(grip, cands.opening_m, cfg.approach_offset_m)
    if support is not None and n:
        low = _lowest_heights(cands.T_base_tcp, halves, centres_tcp, support)
        short = (status == "") & (low < cfg.support_clearance_m)
        if isinstance(grip, ParallelJawGeometry):
            short &= ~_lift_off_support(cands, short, cfg.support_clearance_m - low, support, grip, cfg)
        status[short] = "support"
    timings["filters"] = (time.perf_counter() - t) * 1e3

    # IK, batched.
    t = time.perf_counter()
    T_tcp_flange = invert_T(grip.T_flange_tcp)
    alive = np.flatnonzero(status == "")
    lower, upper = robot.joint_limits
    q_all = np.full((n, 6), np.nan)
    branches = np.full((n, 8, 6), np.nan)
    if alive.size:
        q, ok, br = ik_nearest_batch(robot.spec, cands.T_base_tcp[alive] @ T_tcp_flange, seed, lower, upper)
        q_all[alive], branches[alive] = q, br
        status[alive[~ok]] = "ik"
    timings["ik"] = (time.perf_counter() - t) * 1e3

    # Gripper vs scene, one broadphase query for all survivors. A pose and its flip (half a turn about the
    # approach) occupy the same space (the hulls are symmetric: the fingers swap), so each distinct gripper
    # placement is checked once and its verdict shared.
    t = time.perf_counter()
    alive = np.flatnonzero(status == "")
    if alive.size:
        rep, inverse = _distinct_placements(cands, alive)
        verdict = np.full(len(rep), "", dtype=object)
        check = np.flatnonzero(cands.check_target[rep])
        if check.size and scene.target is not None:
            # A target vertex inside a gripper box is a collision for certain: settled in numpy, so fcl's
            # narrowphase (one Python callback per overlapping pair) only sees the undecided ones.
            inside = _target_points_inside(
                scene.target, cands.T_base_tcp[rep[check]], centres_tcp[rep[check]], halves
            )
            verdict[check[inside]] = "collision_target"
        seen = _seen_points(scene.target, grip)
        if seen is not None:
            t = _SEEN_TOLERANCE_M
            shrunk = [(max(x - t, 0.0), max(y - t, 0.0), max(z - t, 0.0)) for x, y, z in halves]
            open_ = np.flatnonzero(verdict == "")
            strikes = _points_inside(seen, cands.T_base_tcp[rep[open_]], centres_tcp[rep[open_]], shrunk)
            verdict[open_[strikes >= _SEEN_HIT_POINTS]] = "collision_seen"
        todo = np.flatnonzero(verdict == "")
        if todo.size:
            idx = rep[todo]
            T = cands.T_base_tcp[idx]
            centres = centres_tcp[idx] @ np.swapaxes(T[:, :3, :3], 1, 2) + T[:, None, :3, 3]
            hits = scene.boxes_first_hits(
                T[:, :3, :3], centres, halves, include_target=cands.check_target[idx]
            )
            for slot, hit in zip(todo, hits):
                if hit is not None:
                    verdict[slot] = hit.reason
        status[alive] = verdict[inverse]
    timings["gripper_collision"] = (time.perf_counter() - t) * 1e3

    # Rank, then the arm (and the approach / retreat IK) in rank order.
    t = time.perf_counter()
    alive = np.flatnonzero(status == "")
    dist = np.linalg.norm(q_all[alive] - seed, axis=1) if alive.size else np.zeros(0)
    score = cands.quality[alive] - cfg.joint_distance_weight * dist
    order = alive[np.argsort(-score, kind="stable")]
    score_of = dict(zip(alive.tolist(), score.tolist()))
    up = np.array([0.0, 0.0, 1.0]) if support is None else support.normal
    grasps: list[Grasp] = []
    n_unchecked = 0
    chunk = max(4, cfg.max_grasps)
    for start in range(0, len(order), chunk):
        if len(grasps) >= cfg.max_grasps and not cfg.exhaustive:
            n_unchecked += len(order) - start
            break
        idx = order[start : start + chunk]
        T_grasp = cands.T_base_tcp[idx]
        T_pre = T_grasp.copy()
        T_pre[:, :3, 3] -= cfg.approach_offset_m * T_grasp[:, :3, 2]
        T_ret = T_grasp.copy()
        T_ret[:, :3, 3] += cfg.lift_m * up
        # Pre-grasp and retreat on the grasp's branch: the lines from the grasp to them, followed in steps.
        T_from = np.concatenate([T_grasp, T_grasp])
        T_to = np.concatenate([T_pre, T_ret])
        q_from = np.vstack([q_all[idx], q_all[idx]])
        near_ok = _lines_on_branch(robot, T_from, T_to[:, :3, 3] - T_from[:, :3, 3], q_from, T_tcp_flange)
        n_chunk = len(idx)
        approach_ok = near_ok[:n_chunk] & near_ok[n_chunk:]
        q_free = _free_branches(robot, scene, q_all, branches, idx, approach_ok, T_grasp @ T_tcp_flange, cfg)
        for r, i in enumerate(idx):
            if len(grasps) >= cfg.max_grasps and not cfg.exhaustive:
                n_unchecked += 1
                continue
            if not approach_ok[r]:
                status[i] = "ik_approach"
                continue
            q_ok = q_free[r]
            if q_ok is None:
                status[i] = "arm_collision"
                continue
            if len(grasps) < cfg.max_grasps:
                grasps.append(
                    Grasp(
                        T_base_tcp=T_grasp[r],
                        T_base_pregrasp=T_pre[r],
                        T_base_retreat=T_ret[r],
                        opening_m=float(cands.opening_m[i]),
                        width_m=float(cands.width_m[i]),
                        quality=float(cands.quality[i]),
                        reason=cands.reason[i],
                        gripper=grip.kind,
                        method=str(cands.method[i]),
                        contacts=cands.contacts[i],
                        q=q_ok,
                        score=float(score_of[int(i)]),
                    )
                )
    timings["rank_and_arm"] = (time.perf_counter() - t) * 1e3
    timings["total"] = (time.perf_counter() - t0) * 1e3
    rejected.update(s for s in status if s)
    if not grasps:
        err = NoFeasibleGrasp(dict(rejected), n)
        err.timings_ms = timings
        raise err
    log.debug("plan_grasps: %d grasps of %d candidates; rejected %s", len(grasps), n, dict(rejected))
    return GraspPlan(tuple(grasps), dict(rejected), n, n_unchecked, timings)


def _lines_on_branch(
    robot: RobotModel, T_start: np.ndarray, delta: np.ndarray, q_start: np.ndarray, T_tcp_flange: np.ndarray
) -> np.ndarray:
    """(N,) True where the tcp line from `T_start` (N, 4, 4) moved by `delta` (N, 3) [m] stays on the branch
    of `q_start` (N, 6): IK at every `_BRANCH_STEP_M` along it, each seeded with the solution before and
    within `_SAME_BRANCH_RAD` of it. (One jump over a long line is no test: a 34 cm lift near the base
    turns the elbow by more than 1 rad without leaving its branch.)"""
    lower, upper = robot.joint_limits
    length = float(np.max(np.linalg.norm(delta, axis=1))) if len(delta) else 0.0
    n = max(1, math.ceil(length / _BRANCH_STEP_M - 1e-9))
    q = np.array(q_start, dtype=np.float64)
    ok = np.ones(len(q), dtype=bool)
    for k in range(1, n + 1):
        T = np.array(T_start, dtype=np.float64)
        T[:, :3, 3] += delta * (k / n)
        q_k, ok_k, _ = ik_nearest_batch(robot.spec, T @ T_tcp_flange, q, lower, upper)
        ok &= ok_k & (np.linalg.norm(np.nan_to_num(q_k - q, nan=np.inf), axis=1) <= _SAME_BRANCH_RAD)
        q = np.where(ok[:, None], q_k, q)
    return ok


def _free_branches(
    robot: RobotModel,
    scene: CollisionScene,
    q_all: np.ndarray,
    branches: np.ndarray,
    idx: np.ndarray,
    rows_ok: np.ndarray,
    T_base_flange: np.ndarray,
    cfg: GraspConfig,
) -> list[np.ndarray | None]:
    """Per candidate row of `idx` (where `rows_ok`), the first of its `arm_branches` branches (the picked one,
    then the other in-limit ones nearest the seed, each verified by forward kinematics) whose link capsules
    are clear of the scene, or None. One batched arm query per branch rank."""
    out: list[np.ndarray | None] = [None] * len(idx)
    # `branch_order` on arrays: the picked solution, then the other existing branches (nearest first) that
    # differ from it; alt_rank numbers those alternatives 1, 2, ...
    q_first = q_all[idx]
    B = branches[idx]  # (C, 8, 6)
    with np.errstate(invalid="ignore"):
        alt = np.all(np.isfinite(B), axis=2) & (np.max(np.abs(B - q_first[:, None, :]), axis=2) > 1e-9)
    alt_rank = np.where(alt, np.cumsum(alt, axis=1), 0)
    for b in range(cfg.arm_branches):
        if b == 0:
            rows = [r for r in range(len(idx)) if rows_ok[r]]
            Q = q_first[rows]
        else:
            has = alt_rank == b
            rows = [r for r in range(len(idx)) if rows_ok[r] and out[r] is None and has[r].any()]
            Q = B[rows, np.argmax(has[rows], axis=1)] if rows else np.zeros((0, 6))
        if not rows:
            break
        if b > 0:
            # Branches other than the picked one are unverified: keep those whose forward kinematics reach.
            good = fk_reaches(fk_batch(robot.spec, Q), T_base_flange[rows])
            rows, Q = [r for r, g in zip(rows, good) if g], Q[good]
            if not rows:
                continue
        for r, q, hit in zip(rows, Q, scene.arm_hits_batch(robot, Q)):
            if hit is None:
                out[r] = q
    return out


def _distinct_placements(cands: Candidates, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(representative rows, inverse): rows whose gripper fills the same space (same tcp position, approach,
    closing line up to its sign, opening; to 1e-9) share one representative; `inverse` maps each of `rows`
    to its representative's index."""
    T = cands.T_base_tcp[rows]
    y = T[:, :3, 1]
    # The closing line's direction up to sign: flip so that its largest component is positive.
    sign = np.sign(y[np.arange(len(y)), np.argmax(np.abs(y), axis=1)])
    key = np.column_stack([T[:, :3, 3], T[:, :3, 2], y * sign[:, None], cands.opening_m[rows]])
    key = np.ascontiguousarray(np.round(key, 9) + 0.0)  # + 0.0: -0.0 becomes 0.0 (compared bitwise below)
    rows_as_bytes = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, first, inverse = np.unique(rows_as_bytes, return_index=True, return_inverse=True)
    return rows[first], inverse.ravel()


def _target_points_inside(
    target: ObjectModel, T: np.ndarray, centres_tcp: np.ndarray, halves: list[tuple[float, float, float]]
) -> np.ndarray:
    """(N,) True where a vertex of the target (its mesh, at most 256 evenly picked, or its box corners)
    lies inside one of the gripper boxes of pose n."""
    if target.mesh is not None:
        V = np.asarray(target.mesh.vertices, dtype=np.float64)
        V = V[:: max(1, len(V) // 256)]
    else:
        V = target.pose.corners()
    return _points_inside(V, T, centres_tcp, halves) > 0


def _seen_points(
    target: ObjectModel | None, grip: ParallelJawGeometry | SuctionCupGeometry
) -> np.ndarray | None:
    """The target's seen surface points a parallel-jaw gripper's hulls are tested against (at most
    `_SEEN_MAX_POINTS`, evenly picked), or None: no target, no seen surface, or a suction cup (it presses on
    the surface it seals on)."""
    if target is None or target.surface_points is None or not isinstance(grip, ParallelJawGeometry):
        return None
    P = np.asarray(target.surface_points, dtype=np.float64)
    if len(P) < _SEEN_HIT_POINTS:
        return None
    return P[:: max(1, len(P) // _SEEN_MAX_POINTS)]


def _points_inside(
    V: np.ndarray, T: np.ndarray, centres_tcp: np.ndarray, halves: list[tuple[float, float, float]]
) -> np.ndarray:
    """(N,) int: how many of the points V (M, 3) in `base` lie inside one of the gripper boxes (half extents
    `halves`, centres `centres_tcp` (N, K, 3) in the tcp frame) of each pose T (N, 4, 4)."""
    # Point coordinates along each tcp axis in each pose's frame: three (N, M) arrays (elementwise tests on
    # them are much cheaper than reductions over a trailing axis of length 3).
    rel = [V[None, :, j] - T[:, j, 3, None] for j in range(3)]  # base components, (N, M) each
    hit = np.zeros((len(T), len(V)), dtype=bool)
    axes = [
        rel[0] * T[:, 0, a, None] + rel[1] * T[:, 1, a, None] + rel[2] * T[:, 2, a, None] for a in range(3)
    ]
    for k, half in enumerate(halves):
        inside = np.abs(axes[0] - centres_tcp[:, None, k, 0]) <= half[0]
        inside &= np.abs(axes[1] - centres_tcp[:, None, k, 1]) <= half[1]
        inside &= np.abs(axes[2] - centres_tcp[:, None, k, 2]) <= half[2]
        hit |= inside
    return hit.sum(axis=1)
