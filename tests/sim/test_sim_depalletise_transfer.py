"""The depalletising transfer (issue 7): why cartons were lost from the suction cup on the way to the
conveyor, and the planning that keeps them on it. Library geometry in the depalletising cell's layout
(UR16e, pallet at base -x, a 0.5 m conveyor at base +x, its belt 5 cm above the base); the suction physics
is in test_sim_grippers.py. Measured causes (docs/benchmarks.md, depalletising): the carried carton swept
through the conveyor's side guide (its body was not in the collision scene), swung into the arm's own upper
arm or forearm (the held box was checked against the scene only), or was carried at 5-7 m/s^2 (the joint
timing alone)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import invert_T, make_T
from prompose_grasp.grasp.grippers import SuctionCupGeometry
from prompose_grasp.grasp.motion import (
    MotionConfig,
    check_path,
    free_move,
    place_support_fixture,
    timed_held_trajectory,
    timed_trajectory,
)
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import ObjectModel, Plane
from prompose_grasp.robot.model import load_robot

ROBOT = load_robot("ur16e")
CUP = SuctionCupGeometry()
R_DOWN = np.diag([1.0, -1.0, -1.0])  # tcp z pointing down in base
R_OBJ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y (its up) along base z
CARRIED = np.array([0.38, 0.25, 0.25])  # a carton carried as the cell's 0.25 m tall (x, up, depth) [m]
T_TCP_OBJ = make_T(R_DOWN.T @ R_OBJ, [0.0, 0.0, 0.125])  # top-face grasp: the box centre 12.5 cm below
BELT_Z = 0.05  # belt top in base [m] (0.75 m in the world, base 0.7 m up)
# The conveyor along base y at x = 0.55 m, 2 m x 0.5 m (the scene file's conveyor).
CONVEYOR = PlaceTarget("surface", make_T(np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]), [0.55, 0.0, BELT_Z]),
                       [1.0, 0.25])  # fmt: skip
Q_HOME = np.array([-1.5708, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]) + np.array([3.1, 0, 0, 0, 0, 0])


def _tcp_q(p, seed) -> np.ndarray:
    ik = ROBOT.ik(make_T(R_DOWN, p), q_seed=seed, frame="tcp")
    assert ik.success
    return ik.q


def _held(q) -> ObjectModel:
    T = ROBOT.fk(q) @ CUP.T_flange_tcp @ T_TCP_OBJ
    return ObjectModel("carton", Pose9D(T[:3, :3], T[:3, 3], CARRIED))


def _box_corners(Q) -> np.ndarray:
    """(N, 8, 3) corners in base of the carried box at each configuration (forward kinematics)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    local = signs * CARRIED / 2.0
    out = []
    for q in Q:
        T = ROBOT.fk(q) @ CUP.T_flange_tcp @ T_TCP_OBJ
        out.append(local @ T[:3, :3].T + T[:3, 3])
    return np.array(out)


def _dense(W, step_rad=0.01) -> np.ndarray:
    """The joint path through waypoints W sampled every `step_rad` of the largest joint."""
    out = [W[:1]]
    for a, b in itertools.pairwise(W):
        n = max(1, int(np.ceil(np.max(np.abs(b - a)) / step_rad)))
        out.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.vstack(out)


def _over_belt_min_height(Q) -> float:
    """Lowest corner height [m] of the carried box over the conveyor's footprint grown by its rim (4 cm),
    along the path Q: the box's corners' xy within it, or the box straddling it."""
    C = _box_corners(Q)
    lo, hi = C[..., :2].min(axis=1), C[..., :2].max(axis=1)
    fx, fy = 0.25 + 0.04, 1.0 + 0.04  # half extents along base x (across the belt) and y (along it)
    over = (hi[:, 0] > 0.55 - fx) & (lo[:, 0] < 0.55 + fx) & (hi[:, 1] > -fy) & (lo[:, 1] < fy)
    return float(C[over, :, 2].min()) if np.any(over) else np.inf


def test_the_transfer_keeps_the_carton_above_the_conveyor_body():
    """From above a top-layer carton to above the belt: the direct joint line sags on its way down to the
    pre-place and sweeps the carried box into the conveyor's body (below the belt, or through the guide at
    its edge), which the overhead camera does not see; with the conveyor's body as a fixture the transfer
    takes a detour that stays above it."""
    q0 = _tcp_q([-0.55, -0.15, 0.28], Q_HOME)  # lifted above the stack
    q1 = _tcp_q([0.5, -0.4, BELT_Z + 0.25 + 0.005 + 0.10], q0)  # pre-place: 10 cm above the release
    held = _held(q0)
    fixture = place_support_fixture(CONVEYOR)
    assert fixture is not None and fixture.kind == "fixture"
    # Independent check of the sag: the direct line takes the box's bottom below the belt top over the belt.
    assert _over_belt_min_height(_dense(np.array([q0, q1]))) < BELT_Z  # strictly below: no tolerance needed
    scene = CollisionScene([fixture], Plane(np.array([0.0, 0.0, 1.0]), 0.55))  # the pallet's deck, below
    cfg = MotionConfig()
    _, hit = check_path(ROBOT, scene, np.array([q0, q1]), CUP, 0.0, False, held, T_TCP_OBJ, cfg)
    assert hit is not None and hit.name == "place support (held object)"
    W = free_move(
        ROBOT, scene, q0, q1, gripper=CUP, opening_m=0.0, held=held, T_tcp_obj=T_TCP_OBJ, config=cfg
    )
    assert len(W) > 2  # a detour, not the direct line
    assert np.allclose(W[0], q0) and np.allclose(W[-1], q1)  # default 1e-8: the ends are the inputs
    # 3 mm: the collision check shrinks the carried box by `contact_margin_m` (it rests on its support).
    assert _over_belt_min_height(_dense(W)) >= BELT_Z - cfg.contact_margin_m


def test_place_support_fixture_is_only_for_a_surface_the_arm_does_not_stand_on():
    """A bin's walls and a pallet's deck are targets of their own; a table the arm is mounted on is the
    support plane (a fixture around the base would block every move)."""
    T = CONVEYOR.T_base_surface
    assert place_support_fixture(PlaceTarget("bin", T, [0.2, 0.15], 0.1)) is None
    assert place_support_fixture(PlaceTarget("pallet", T, [0.6, 0.4])) is None
    assert (
        place_support_fixture(PlaceTarget("surface", make_T(np.eye(3), [0.3, 0.0, -0.02]), [0.5, 0.5]))
        is None
    )
    box = place_support_fixture(CONVEYOR)
    # Its top is the belt, its footprint the belt and the 4 cm rim (known answer from the target).
    corners = box.pose.corners()
    assert corners[:, 2].max() == pytest.approx(BELT_Z, abs=1e-9)  # exact: built from the surface
    assert corners[:, 0].min() == pytest.approx(0.55 - 0.29, abs=1e-9)  # 1e-9: float rounding (as above)
    assert corners[:, 1].max() == pytest.approx(1.04, abs=1e-9)  # 1e-9: float rounding (as above)


def test_a_carried_box_swung_into_the_upper_arm_is_a_collision():
    """The held box is checked against the arm's own links: a box put (by its grasp) where the upper arm
    passes at the end of a move is hit there, and nothing else on the path is (the scene is empty)."""
    q1 = np.array([0.0, -1.6, 1.2, -1.57, -1.57, 0.0])
    q0 = q1 + np.array([0.0, 0.0, 0.0, -1.5, 0.0, 0.0])  # wrist 1 swings the box round
    frames = ROBOT.link_frames(q1)
    mid = frames[2] @ np.array([-0.2392, 0.0, 0.0, 1.0])  # the upper arm capsule's midpoint at q1
    T_flange_obj = invert_T(ROBOT.fk(q1)) @ make_T(np.eye(3), mid[:3])
    T_tcp_obj = invert_T(CUP.T_flange_tcp) @ T_flange_obj
    T0 = ROBOT.fk(q0) @ T_flange_obj
    held = ObjectModel("box", Pose9D(T0[:3, :3], T0[:3, 3], np.full(3, 0.1)))
    # Independent: at q0 the box's centre is far from the upper arm's axis segment (0.68 m against the box's
    # 0.09 m half diagonal and the capsule's 0.075 m radius); at q1 it is on it.
    a, b = (ROBOT.link_frames(q0)[2] @ np.array([[0, 0, 0, 1.0], [-0.4784, 0, 0, 1.0]]).T)[:3].T
    s = np.clip((T0[:3, 3] - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    assert np.linalg.norm(T0[:3, 3] - (a + s * (b - a))) > 0.3
    scene = CollisionScene()
    _, hit = check_path(ROBOT, scene, np.array([q0, q1]), CUP, 0.0, False, held, T_tcp_obj)
    assert hit is not None and "upper_arm_link" in hit.name
    _, hit = check_path(ROBOT, scene, np.array([q0, q1]), CUP, 0.0, False)  # nothing held: free
    assert hit is None


def test_suction_held_moves_are_timed_to_the_cups_acceleration():
    """A shoulder-and-elbow move timed by the joint limits alone accelerates the held box's centre past
    the suction cap (3 m/s^2); the held timing is the same path, slower, under the cap, measured here by
    forward kinematics of its samples (central differences, independent of `held_acceleration`)."""
    q0 = np.array([0.0, -1.2, 1.6, -1.97, -1.57, 0.0])
    W = np.array([q0, q0 + np.array([0.0, -0.8, -1.0, 0.0, 0.0, 0.0])])
    cfg = MotionConfig()
    T_flange_point = CUP.T_flange_tcp @ T_TCP_OBJ

    def peak(traj) -> float:
        Q = np.vstack([W[:1], W[:1], traj.q, traj.q[-1:]])
        P = np.array([(ROBOT.fk(q) @ T_flange_point)[:3, 3] for q in Q])
        dt = float(traj.t_s[1] - traj.t_s[0])
        return float(np.max(np.linalg.norm(P[2:] - 2.0 * P[1:-1] + P[:-2], axis=1)) / dt**2)

    fast = timed_trajectory(ROBOT, W, cfg)
    slow = timed_held_trajectory(ROBOT, W, cfg, T_flange_point, cfg.suction_held_accel_m_s2)
    assert peak(fast) > 4.0  # 4.8 m/s^2: over the cup's cap, the load that lost cartons
    assert peak(slow) <= cfg.suction_held_accel_m_s2 + 1e-6  # 1e-6: float rounding of the differences
    # allclose's default 1e-8: the last sample is the goal itself (float rounding of the profile).
    assert np.allclose(slow.q[-1], W[-1]) and slow.t_s[-1] > fast.t_s[-1]
    # The same path: every slow sample lies on the segment W[0] -> W[1] (joint space).
    s = (slow.q - W[0]) @ (W[1] - W[0]) / float((W[1] - W[0]) @ (W[1] - W[0]))
    assert np.allclose(slow.q, W[0] + s[:, None] * (W[1] - W[0]), atol=1e-9)  # 1e-9: float rounding
