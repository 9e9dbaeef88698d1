"""Place planning and pick-and-place motion: collision-free against a wall, at the promised resolution."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from prompose_grasp.errors import NoFeasiblePlace
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp import (
    CollisionScene,
    GripperAction,
    MotionConfig,
    ObjectModel,
    PalletPattern,
    ParallelJawGeometry,
    PlaceTarget,
    Plane,
    SuctionCupGeometry,
    check_path,
    pallet_layout,
    pallet_slots,
    plan_grasps,
    plan_pick_place,
    plan_place,
)
from prompose_grasp.robot import HOME_Q, load_robot

R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
JAW = ParallelJawGeometry()
ROBOT = load_robot("ur5e", tcp_offset=JAW.T_flange_tcp)
TABLE = Plane.horizontal(0.0)


def _inside_box(points, pose: Pose9D) -> np.ndarray:
    local = (points - pose.t) @ pose.R
    return np.all(np.abs(local) <= pose.size / 2, axis=-1)


@pytest.fixture(scope="module")
def wall_motion():
    box = ObjectModel("box", Pose9D(R_UP, [-0.5, 0.15, 0.03], [0.05, 0.06, 0.06]))
    # A 2 cm thick, 30 cm tall wall between the box and the place area.
    wall = ObjectModel("wall", Pose9D(np.eye(3), [-0.45, -0.1, 0.15], [0.4, 0.02, 0.3]), kind="fixture")
    grasp = plan_grasps(box, ROBOT, JAW, [wall], TABLE, None, HOME_Q).best
    target = PlaceTarget("surface", make_T(np.eye(3), [-0.45, -0.35, 0.0]), [0.12, 0.12])
    place = plan_place(box, grasp, target, ROBOT, JAW, [wall])
    scene_pick = CollisionScene([wall], TABLE, None, box)
    scene_held = CollisionScene([wall], TABLE, None, None)
    motion = plan_pick_place(ROBOT, grasp, place, box, scene_pick, scene_held, JAW, HOME_Q)
    return box, wall, grasp, place, target, scene_held, motion


def test_segments_in_order_within_limits_and_clear_of_the_wall(wall_motion):
    box, wall, grasp, place, _, _, motion = wall_motion
    assert [s.name for s in motion.segments] == [
        "to_pregrasp",
        "approach",
        "lift",
        "transfer",
        "descend",
        "retreat",
    ]
    # The gripper closes once the approach ends and opens once the descent to the place pose ends; it
    # holds the object over exactly the segments in between.
    assert [s.gripper_after for s in motion.segments] == [
        GripperAction.NONE,
        GripperAction.CLOSE,
        GripperAction.NONE,
        GripperAction.NONE,
        GripperAction.OPEN,
        GripperAction.NONE,
    ]
    assert [s.holding for s in motion.segments] == [False, False, True, True, True, False]
    lower, upper = ROBOT.joint_limits
    wall_grown = Pose9D(wall.pose.R, wall.pose.t, wall.pose.size)
    for seg in motion.segments:
        assert np.all(seg.path >= lower) and np.all(seg.path <= upper)
        # Consecutive segments join.
        for q in seg.path:
            T = ROBOT.fk_tcp(q)
            # Independent check: the tcp, the flange and every arm capsule end stay out of the wall.
            pts = [T[:3, 3], ROBOT.fk(q)[:3, 3]] + [
                p for _, p0, p1, _ in ROBOT.capsules_in_base(q) for p in (p0, p1)
            ]
            assert not np.any(_inside_box(np.array(pts), wall_grown)), seg.name
        np.testing.assert_allclose(seg.trajectory.q[-1], seg.waypoints[-1], atol=1e-12)  # timed to the end
    names = [s.name for s in motion.segments]
    for a, b in itertools.pairwise(names):
        np.testing.assert_allclose(motion.segment(a).waypoints[-1], motion.segment(b).waypoints[0], atol=1e-9)
    np.testing.assert_allclose(motion.segment("approach").waypoints[-1], grasp.q, atol=1e-12)
    np.testing.assert_allclose(
        ROBOT.fk_tcp(motion.segment("descend").waypoints[-1]), place.T_base_tcp, atol=1e-9
    )
    # The held box goes over the wall: its lowest point on the transfer clears the wall's top (30 cm).
    T_tcp_obj = np.linalg.inv(grasp.T_base_tcp) @ box.pose.to_matrix()
    transfer = motion.segment("transfer").path
    centres = np.array([(ROBOT.fk_tcp(q) @ T_tcp_obj)[:3, 3] for q in transfer])
    over = np.abs(centres[:, 1] - wall.pose.t[1]) < 0.05
    assert np.any(over) and np.all(centres[over, 2] - 0.03 > 0.3 - 1e-3)  # 1 mm: the box shrink margin


def test_direct_transfer_would_hit_the_wall_and_resolution_holds(wall_motion):
    box, _wall, grasp, _place, _, scene_held, motion = wall_motion
    T_tcp_obj = np.linalg.inv(grasp.T_base_tcp) @ box.pose.to_matrix()
    lift_end = motion.segment("lift").waypoints[-1]
    preplace = motion.segment("descend").waypoints[0]
    _, hit = check_path(
        ROBOT, scene_held, np.array([lift_end, preplace]), JAW, grasp.opening_m, False, box, T_tcp_obj
    )
    assert hit is not None and hit.name.startswith("wall")
    # Between checked samples no point of the tcp / flange moves more than the resolution (5 mm).
    res = MotionConfig().resolution_m
    for seg in motion.segments:
        tcp = np.array([ROBOT.fk_tcp(q)[:3, 3] for q in seg.path])
        assert np.max(np.linalg.norm(np.diff(tcp, axis=0), axis=1)) <= res + 1e-12


def test_place_on_surface_rests_the_box_inside(wall_motion):
    box, _, _, place, target, _, _ = wall_motion
    T_surf = target.T_base_surface
    local = np.linalg.inv(T_surf) @ place.T_base_obj
    assert abs(local[2, 3] - (0.03 + 0.005)) < 1e-12  # half height + the drop clearance
    corners = Pose9D(place.T_base_obj[:3, :3], place.T_base_obj[:3, 3], box.pose.size).corners()
    corners_s = (corners - T_surf[:3, 3]) @ T_surf[:3, :3]
    assert np.all(np.abs(corners_s[:, :2]) <= target.half_extents_xy_m + 1e-12)
    np.testing.assert_allclose(
        place.T_base_preplace[:3, 3], place.T_base_tcp[:3, 3] + [0, 0, 0.1], atol=1e-12
    )


def test_pallet_slots_fill_in_order():
    cup = SuctionCupGeometry()
    robot = load_robot("ur10e", tcp_offset=cup.T_flange_tcp)
    size = np.array([0.3, 0.2, 0.2])  # obj x, y (up), z
    carton = ObjectModel("carton", Pose9D(R_UP, [0.0, -0.7, 0.1], size), family="carton")
    grasp = plan_grasps(carton, robot, cup, [], TABLE, None, HOME_Q).best
    pallet = PlaceTarget(
        "pallet", make_T(np.eye(3), [0.0, 0.7, 0.1]), [0.4, 0.3], pattern=PalletPattern(2, 2, 2, 0.01)
    )
    slots = pallet_slots(pallet, np.array([0.15, 0.1]), 0.1)
    assert [s for s, _ in slots][:5] == [(0, 0, 0), (0, 1, 0), (1, 0, 0), (1, 1, 0), (0, 0, 1)]
    np.testing.assert_allclose(slots[0][1], [-0.155, -0.105, 0.1], atol=1e-12)  # pitch = carton + gap
    first = plan_place(carton, grasp, pallet, robot, cup)
    assert first.slot == (0, 0, 0)
    # Slot (0, 0, 0) taken by an earlier carton: the next is (0, 1, 0); a second layer needs support below.
    T_s = pallet.T_base_surface
    placed = [ObjectModel("c0", Pose9D(R_UP, T_s[:3, 3] + slots[0][1], size), family="carton")]
    second = plan_place(carton, grasp, pallet, robot, cup, placed)
    assert second.slot == (0, 1, 0)
    full = [ObjectModel(f"c{k}", Pose9D(R_UP, T_s[:3, 3] + c, size)) for k, (_, c) in enumerate(slots[:4])]
    assert plan_place(carton, grasp, pallet, robot, cup, full).slot == (0, 0, 1)
    everything = [ObjectModel(f"c{k}", Pose9D(R_UP, T_s[:3, 3] + c, size)) for k, (_, c) in enumerate(slots)]
    with pytest.raises(NoFeasiblePlace):
        plan_place(carton, grasp, pallet, robot, cup, everything)


def test_a_pallet_pattern_larger_than_the_deck_is_no_feasible_place():
    cup = SuctionCupGeometry()
    robot = load_robot("ur10e", tcp_offset=cup.T_flange_tcp)
    size = np.array([0.3, 0.2, 0.2])  # obj x, y (up), z: a 0.3 x 0.2 m footprint
    carton = ObjectModel("carton", Pose9D(R_UP, [0.0, -0.7, 0.1], size), family="carton")
    grasp = plan_grasps(carton, robot, cup, [], TABLE, None, HOME_Q).best
    # 2 x 2 cartons with a 1 cm gap need 0.61 x 0.41 m; the deck is 0.5 x 0.4 m.
    small = PlaceTarget(
        "pallet", make_T(np.eye(3), [0.0, 0.7, 0.1]), [0.25, 0.2], pattern=PalletPattern(2, 2, 1, 0.01)
    )
    with pytest.raises(NoFeasiblePlace) as info:
        plan_place(carton, grasp, small, robot, cup)
    assert info.value.rejected == {"pattern_too_large": 1}
    assert "does not fit the deck" in str(info.value.__cause__)
    # The same pattern on a deck 1 cm larger each way than it needs has a place: the check is the fit.
    fits = PlaceTarget(
        "pallet", make_T(np.eye(3), [0.0, 0.7, 0.1]), [0.315, 0.215], pattern=PalletPattern(2, 2, 1, 0.01)
    )
    assert plan_place(carton, grasp, fits, robot, cup).slot == (0, 0, 0)


def _moving_points(q: np.ndarray, opening: float) -> np.ndarray:
    """Points of the arm and the gripper at q, computed independently of the planner: both ends of every link
    capsule, and the 8 corners of every gripper part at the opening."""
    pts = [p for _, p0, p1, _ in ROBOT.capsules_in_base(q) for p in (p0, p1)]
    T_tcp = ROBOT.fk_tcp(q)
    for part in JAW.parts(opening):
        lo, hi = part.aabb_tcp()
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        pts += list(corners @ T_tcp[:3, :3].T + T_tcp[:3, 3])
    return np.array(pts)


def test_a_1cm_wall_is_caught_at_the_derived_resolution_and_missed_when_under_resolved():
    # Turning the base by 1 rad swings the gripper through a 1 cm thick wall standing across its path at
    # 40 % of the way; the wall is small (12 x 6 cm, wider than the open jaws) and only meets the gripper.
    q0 = np.array(HOME_Q, dtype=np.float64)
    q1 = q0 + np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    s = 0.4
    q_mid = q0 + s * (q1 - q0)
    T_mid = ROBOT.fk_tcp(q_mid)
    p = T_mid[:3, 3]
    tangent = np.cross([0.0, 0.0, 1.0], p)  # the tcp moves about the base z axis
    tangent /= np.linalg.norm(tangent)
    radial = np.cross([0.0, 0.0, 1.0], tangent)
    R_wall = np.stack([tangent, radial, [0.0, 0.0, 1.0]], axis=1)
    wall = ObjectModel("thin wall", Pose9D(R_wall, p, [0.01, 0.12, 0.06]), kind="fixture")
    scene = CollisionScene([wall])
    opening = JAW.stroke_m
    _, hit = check_path(ROBOT, scene, np.array([q0, q1]), JAW, opening, False)
    assert hit is not None and hit.name.startswith("thin wall")
    # Checking only the ends (a resolution coarser than the whole move) steps over it.
    S_coarse, hit_coarse = check_path(
        ROBOT, scene, np.array([q0, q1]), JAW, opening, False, config=MotionConfig(resolution_m=10.0)
    )
    assert len(S_coarse) == 2 and hit_coarse is None
    # The resolution is derived from the largest displacement per step: between neighbouring checked
    # samples of the full path no capsule end or gripper corner moves more than resolution_m (5 mm), so
    # nothing can jump a 1 cm wall.
    res = MotionConfig().resolution_m
    S_all, _ = check_path(ROBOT, CollisionScene([]), np.array([q0, q1]), JAW, opening, False)
    P = np.array([_moving_points(q, opening) for q in S_all])  # (M, K, 3)
    step = np.linalg.norm(np.diff(P, axis=0), axis=2).max()
    assert step <= res + 1e-12
    # The bound (DH offsets beyond each joint + tool) is conservative: a base turn moves the gripper ~2.6x
    # less than it allows here; within 5x keeps the sample count sane.
    assert step > 0.2 * res


def _boxes_overlap(a: Pose9D, b: Pose9D) -> bool:
    """Independent separating-axis test of two boxes (15 axes, plain loops)."""
    axes = [a.R[:, i] for i in range(3)] + [b.R[:, i] for i in range(3)]
    axes += [np.cross(a.R[:, i], b.R[:, j]) for i in range(3) for j in range(3)]
    d = b.t - a.t
    for ax in axes:
        n = np.linalg.norm(ax)
        if n < 1e-9:
            continue
        ax = ax / n
        ra = np.sum(np.abs(a.R.T @ ax) * a.size / 2)
        rb = np.sum(np.abs(b.R.T @ ax) * b.size / 2)
        if abs(d @ ax) > ra + rb:
            return False
    return True


def _on(index, low, high):
    """The lower-layer slots the upper slot `index` rests on."""
    s = next(h for h in high if h.index == index)
    return [
        b for b in low if np.all(np.abs(b.centre_m[:2] - s.centre_m[:2]) < b.half_xy_m + s.half_xy_m - 0.01)
    ]


def test_interlocked_pallet_layers_cross_their_seams_and_places_are_collision_checked():
    cup = SuctionCupGeometry()
    robot = load_robot("ur10e", tcp_offset=cup.T_flange_tcp)
    size = np.array([0.3, 0.16, 0.2])  # obj x, y (up), z: a 30 x 20 cm footprint, 16 cm tall
    carton = ObjectModel("carton", Pose9D(R_UP, [0.0, -0.7, 0.08], size), family="carton")
    grasp = plan_grasps(carton, robot, cup, [], TABLE, None, HOME_Q).best
    pattern = PalletPattern(rows=3, cols=2, layers=2, gap_m=0.01, interlock=True)
    pallet = PlaceTarget("pallet", make_T(np.eye(3), [0.0, 0.75, 0.1]), [0.35, 0.35], pattern=pattern)
    layout = pallet_layout(pallet, np.array([0.15, 0.1]), 0.08)
    low = [s for s in layout if s.index[2] == 0]
    high = [s for s in layout if s.index[2] == 1]
    assert len(low) == len(high) == 6
    assert all(s.yaw_rad == 0.0 for s in low) and all(s.yaw_rad == pytest.approx(np.pi / 2) for s in high)
    np.testing.assert_allclose(high[0].half_xy_m, [0.1, 0.15], atol=1e-12)  # the turned footprint
    # Both layers cover the same 61 x 62 / 62 x 61 cm area, and every upper carton bridges >= 2 lower ones
    # (no seam runs straight through two layers).
    for layer in (low, high):
        lo = np.min([s.centre_m[:2] - s.half_xy_m for s in layer], axis=0)
        hi = np.max([s.centre_m[:2] + s.half_xy_m for s in layer], axis=0)
        assert np.all(np.abs(hi - lo - 0.615) <= 0.005 + 1e-12)  # 0.61 or 0.62 m: carton sizes + gaps
    for s in high:
        under = [
            b
            for b in low
            if np.all(np.abs(b.centre_m[:2] - s.centre_m[:2]) < b.half_xy_m + s.half_xy_m - 0.01)
        ]
        assert len(under) >= 2
    T_s = pallet.T_base_surface

    def placed(slots):
        out = []
        for k, sl in enumerate(slots):
            c, sn = np.cos(sl.yaw_rad), np.sin(sl.yaw_rad)
            R = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]]) @ R_UP
            out.append(ObjectModel(f"c{k}", Pose9D(R, T_s[:3, 3] + sl.centre_m, size), family="carton"))
        return out

    # Layer 0 complete: the next place is on layer 1, turned a quarter turn, resting on the cartons below
    # without overlapping any of them (3 mm: the place check's box shrink).
    below = placed(low)
    place = plan_place(carton, grasp, pallet, robot, cup, below)
    assert place.slot is not None and place.slot[2] == 1
    R_rel = R_UP.T @ place.T_base_obj[:3, :3]
    np.testing.assert_allclose(np.abs(R_rel), np.abs(np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0]])), atol=1e-9)
    shrunk = Pose9D(place.T_base_obj[:3, :3], place.T_base_obj[:3, 3], size - 0.006)
    assert not any(_boxes_overlap(shrunk, o.pose) for o in below)
    # With one lower carton missing, no upper slot resting on it is offered.
    missing = low[0]
    partial = plan_place(carton, grasp, pallet, robot, cup, placed([s for s in low if s is not missing]))
    assert partial.slot == missing.index  # the hole is filled first (layer by layer)
    # A stray box reaching 2.5 cm into the free slot (its centre outside it, so the slot is not "taken"):
    # that slot is rejected by the collision check, and the upper slots resting on it wait.
    stray_c = T_s[:3, 3] + missing.centre_m + [missing.half_xy_m[0] + 0.01, 0.0, 0.0]
    stray = ObjectModel("stray", Pose9D(np.eye(3), stray_c, [0.07, 0.05, 0.05]))
    blocked = plan_place(carton, grasp, pallet, robot, cup, [*placed(low[1:]), stray])
    assert blocked.slot is not None and blocked.slot[2] == 1
    assert missing.index not in [b.index for b in _on(blocked.slot, low, high)]


def test_bin_place_is_inside_the_walls_and_clear_of_what_is_already_in_it():
    box = ObjectModel("box", Pose9D(R_UP, [-0.5, 0.15, 0.03], [0.05, 0.06, 0.06]))
    grasp = plan_grasps(box, ROBOT, JAW, [], TABLE, None, HOME_Q).best
    T_bin = make_T(np.eye(3), [-0.3, -0.45, 0.02])
    half, wall_h = np.array([0.12, 0.1]), 0.12
    walls = [
        ObjectModel(f"wall{k}", Pose9D(np.eye(3), T_bin[:3, 3] + c, s), kind="fixture")
        for k, (c, s) in enumerate(
            [
                ([half[0] + 0.005, 0, wall_h / 2], [0.01, 2 * half[1] + 0.02, wall_h]),
                ([-half[0] - 0.005, 0, wall_h / 2], [0.01, 2 * half[1] + 0.02, wall_h]),
                ([0, half[1] + 0.005, wall_h / 2], [2 * half[0], 0.01, wall_h]),
                ([0, -half[1] - 0.005, wall_h / 2], [2 * half[0], 0.01, wall_h]),
            ]
        )
    ]
    inside = ObjectModel("inside", Pose9D(np.eye(3), T_bin[:3, 3] + [0.0, 0.0, 0.04], [0.08, 0.08, 0.08]))
    target = PlaceTarget("bin", T_bin, half, wall_height_m=wall_h)
    place = plan_place(box, grasp, target, ROBOT, JAW, [*walls, inside])
    placed = Pose9D(place.T_base_obj[:3, :3], place.T_base_obj[:3, 3], box.pose.size)
    corners = (placed.corners() - T_bin[:3, 3]) @ T_bin[:3, :3]
    assert np.all(np.abs(corners[:, :2]) <= half - 0.01 + 1e-9)  # 1 cm wall margin
    assert not _boxes_overlap(placed, inside.pose)
    # The open jaws at the release pose clear the walls and the box already inside (their parts, checked
    # here against the obstacle boxes with the independent test).
    for part in JAW.parts(grasp.opening_m):
        lo, hi = part.aabb_tcp()
        part_box = Pose9D(
            place.T_base_tcp[:3, :3],
            place.T_base_tcp[:3, :3] @ ((lo + hi) / 2) + place.T_base_tcp[:3, 3],
            hi - lo,
        )
        assert not any(_boxes_overlap(part_box, o.pose) for o in [*walls, inside]), part.name
    # Without the box inside, the centre (the preferred point) is taken.
    free = plan_place(box, grasp, target, ROBOT, JAW, walls)
    np.testing.assert_allclose((free.T_base_obj[:3, 3] - T_bin[:3, 3])[:2], [0.0, 0.0], atol=0.02 + 1e-9)
