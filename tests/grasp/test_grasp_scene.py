"""The fcl scene: what a query touches, against independent geometry."""

from __future__ import annotations

import fcl
import numpy as np

from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.se3 import make_T, random_rotation
from prompose_grasp.grasp import CollisionScene, ObjectModel, Plane, voxelize_points


def _sat_overlap(Ra, ca, ha, Rb, cb, hb) -> bool:
    """Separating-axis test of two oriented boxes (independent of fcl)."""
    axes = [Ra[:, i] for i in range(3)] + [Rb[:, i] for i in range(3)]
    axes += [np.cross(Ra[:, i], Rb[:, j]) for i in range(3) for j in range(3)]
    d = cb - ca
    for ax in axes:
        n = np.linalg.norm(ax)
        if n < 1e-9:
            continue
        ax = ax / n
        ra = np.sum(np.abs(Ra.T @ ax) * ha)
        rb = np.sum(np.abs(Rb.T @ ax) * hb)
        if abs(d @ ax) > ra + rb:
            return False
    return True


def test_batched_box_queries_agree_with_separating_axes():
    rng = np.random.default_rng(21)
    obstacles = [
        ObjectModel(
            f"o{i}", Pose9D(random_rotation(rng), rng.uniform(-0.3, 0.3, 3), rng.uniform(0.03, 0.12, 3))
        )
        for i in range(6)
    ]
    scene = CollisionScene(obstacles)
    n = 300
    R = np.stack([random_rotation(rng) for _ in range(n)])
    halves = [(0.02, 0.03, 0.05), (0.01, 0.01, 0.02)]
    centres = np.stack([rng.uniform(-0.4, 0.4, (n, 3)), rng.uniform(-0.4, 0.4, (n, 3))], axis=1)
    hits = scene.boxes_first_hits(R, centres, halves)
    disagree = 0
    for i in range(n):
        expected = any(
            _sat_overlap(R[i], centres[i, k], np.array(halves[k]), o.pose.R, o.pose.t, o.pose.size / 2)
            for k in range(2)
            for o in obstacles
        )
        disagree += expected != (hits[i] is not None)
        if hits[i] is not None:
            assert hits[i].kind == "object" and hits[i].reason == "collision_object"
    # fcl's GJK/EPA box-box answers near touching configurations can differ from SAT by rounding only.
    assert disagree == 0


def test_support_points_and_target_are_told_apart():
    table = Plane.horizontal(0.0)
    target = ObjectModel("t", Pose9D(np.eye(3), [0.0, 0.0, 0.05], [0.05, 0.05, 0.1]))
    rng = np.random.default_rng(2)
    on_target = rng.uniform([-0.025, -0.025, 0.0], [0.025, 0.025, 0.1], (500, 3))
    on_table = np.column_stack([rng.uniform(-0.5, 0.5, (500, 2)), np.full(500, 0.002)])
    clutter = rng.uniform([0.2, 0.2, 0.0], [0.24, 0.24, 0.05], (300, 3))
    scene = CollisionScene([], table, np.vstack([on_target, on_table, clutter]), target, voxel_size_m=0.01)
    # Only the clutter is left as voxels: within its 4 x 4 x 5 cm block (+ one voxel of rounding).
    assert len(scene.voxel_centres) > 0
    assert np.all(scene.voxel_centres >= [0.19, 0.19, 0.0]) and np.all(
        scene.voxel_centres <= [0.25, 0.25, 0.06]
    )
    box = fcl.Box(0.02, 0.02, 0.02)
    assert (
        scene.collide_object(fcl.CollisionObject(box, fcl.Transform(np.array([0.22, 0.22, 0.03])))).kind
        == "points"
    )
    assert (
        scene.collide_object(fcl.CollisionObject(box, fcl.Transform(np.array([0.0, 0.0, 0.05])))).kind
        == "target"
    )
    below = fcl.CollisionObject(box, fcl.Transform(np.array([-0.3, 0.0, 0.005])))
    assert scene.collide_object(below).kind == "support"
    assert scene.collide_object(below, include_support=False) is None
    assert scene.collide_object(fcl.CollisionObject(box, fcl.Transform(np.array([-0.3, 0.0, 0.05])))) is None


def test_voxels_cover_their_points_and_plane_from_camera_round_trip():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.1, 0.1, (1000, 3))
    centres = voxelize_points(pts, 0.01)
    # Every point lies in some voxel (within half an edge of a centre along every axis).
    d = np.abs(pts[:, None, :] - centres[None]).max(axis=2).min(axis=1)
    assert np.all(d <= 0.005 + 1e-12)
    T_base_cam = make_T(random_rotation(rng), rng.uniform(-1, 1, 3))
    n_cam = np.array([0.1, -0.9, -0.3])
    n_cam /= np.linalg.norm(n_cam)
    plane = Plane.from_camera(n_cam, 0.8, T_base_cam)
    x_cam = rng.normal(size=(20, 3))
    x_base = x_cam @ T_base_cam[:3, :3].T + T_base_cam[:3, 3]
    np.testing.assert_allclose(plane.height(x_base), x_cam @ n_cam + 0.8, atol=1e-12)  # same heights


def _clutter(rng):
    """Box obstacles, a mesh obstacle, a fixture, observed points (voxels), a mesh target and the table."""
    import trimesh

    table = Plane.horizontal(0.0)
    boxes = [
        ObjectModel(f"o{i}", Pose9D(random_rotation(rng), rng.uniform([-0.7, -0.3, 0.05], [-0.3, 0.3, 0.3]),
                                    rng.uniform(0.03, 0.12, 3)))
        for i in range(4)
    ]  # fmt: skip
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=24)
    mesh.apply_translation([-0.45, 0.2, 0.06])
    mug = ObjectModel("cyl", Pose9D(np.eye(3), [-0.45, 0.2, 0.06], [0.08, 0.08, 0.12]), mesh=mesh)
    wall = ObjectModel("wall", Pose9D(np.eye(3), [-0.5, -0.35, 0.15], [0.4, 0.01, 0.3]), kind="fixture")
    # A carton given as a box mesh (a prior's mesh) in a tilted pose: the scene treats it as its box.
    R_c = random_rotation(rng)
    carton_mesh = trimesh.creation.box(extents=[0.1, 0.08, 0.06])
    carton_mesh.apply_transform(make_T(R_c, [-0.65, 0.05, 0.2]))
    carton = ObjectModel("carton", Pose9D(R_c, [-0.65, 0.05, 0.2], [0.1, 0.08, 0.06]), mesh=carton_mesh)
    target_mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    target_mesh.apply_translation([-0.5, 0.0, 0.04])
    target = ObjectModel("ball", Pose9D(np.eye(3), [-0.5, 0.0, 0.04], [0.08, 0.08, 0.08]), mesh=target_mesh)
    points = rng.uniform([-0.35, -0.15, 0.0], [-0.25, 0.0, 0.15], (800, 3))  # an unmodelled block
    scene = CollisionScene([*boxes, mug, wall, carton], table, points, target)
    assert list(scene._item_kind[: len(boxes) + 3]) == [0] * len(boxes) + [1, 0, 0]  # mesh, wall, carton
    return scene, [*boxes, mug, wall, carton]


def _fcl_first(scene, objects, include_target) -> bool:
    """Independent answer: every query object against every scene fcl object, pairwise (no broadphase)."""
    request = fcl.CollisionRequest()
    others = [o for o, _, _ in scene._items] + ([scene.target_object] if include_target else [])
    return any(fcl.collide(a, b, request, fcl.CollisionResult()) for a in objects for b in others)


def test_batched_boxes_against_meshes_voxels_and_target_agree_with_pairwise_fcl():
    rng = np.random.default_rng(4)
    scene, _ = _clutter(rng)
    assert len(scene.voxel_centres) > 0
    n = 400
    R = np.stack([random_rotation(rng) for _ in range(n)])
    halves = [(0.01, 0.04, 0.02), (0.005, 0.01, 0.03)]
    centres = rng.uniform([-0.75, -0.4, 0.0], [-0.2, 0.35, 0.3], (n, 1, 3)) + np.array(
        [[0.0, 0.0, 0.0], [0.0, 0.03, 0.0]]
    )
    include_target = rng.uniform(size=n) < 0.5
    hits = scene.boxes_first_hits(R, centres, halves, include_target)
    kinds = set()
    for i in range(n):
        objs = [
            fcl.CollisionObject(fcl.Box(*(2 * np.array(h))), fcl.Transform(R[i], centres[i, k]))
            for k, h in enumerate(halves)
        ]
        assert (hits[i] is not None) == _fcl_first(scene, objs, include_target[i]), i
        if hits[i] is not None:
            kinds.add(hits[i].kind)
    assert kinds == {"object", "fixture", "points", "target"}  # every kind of item was exercised


def test_batched_arm_check_agrees_with_the_single_one():
    from prompose_grasp.robot import load_robot

    rng = np.random.default_rng(8)
    scene, _ = _clutter(rng)
    robot = load_robot("ur5e")
    Q = robot.random_configurations(rng, 150)
    box = fcl.Box(0.04, 0.09, 0.06)
    T_flange_part = make_T(np.eye(3), [0.0, 0.0, 0.1])
    extra = [("gripper box", box, T_flange_part, np.array([0.02, 0.045, 0.03]), "box")]
    batch = scene.arm_hits_batch(robot, Q, extra=extra)
    single_obj = fcl.CollisionObject(box, fcl.Transform())
    n_hit = 0
    for q, hit in zip(Q, batch):
        T = robot.fk(q) @ T_flange_part
        single_obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
        single = scene.arm_hit(robot, q, extra=[("gripper box", single_obj)])
        assert (hit is None) == (single is None), (q, hit, single)
        n_hit += hit is not None
    assert 0 < n_hit < len(Q)  # both verdicts occur


def test_segment_box_distance_matches_dense_sampling():
    from prompose_grasp.geometry.distance import segment_box_distance

    rng = np.random.default_rng(12)
    n = 300
    p0, p1 = rng.uniform(-0.3, 0.3, (n, 3)), rng.uniform(-0.3, 0.3, (n, 3))
    p1[:20] = p0[:20]  # points
    c = rng.uniform(-0.1, 0.1, (n, 3))
    R = np.stack([random_rotation(rng) for _ in range(n)])
    R[20:40] = np.eye(3)  # axis-aligned boxes
    p1[20:40, 1] = p0[20:40, 1]  # segments parallel to a face
    h = rng.uniform(0.01, 0.1, (n, 3))
    d = segment_box_distance(p0, p1, c, R, h)
    t = np.linspace(0.0, 1.0, 4001)
    for i in range(n):
        local = (p0[i] + t[:, None] * (p1[i] - p0[i]) - c[i]) @ R[i]
        dense = np.sqrt(np.sum(np.maximum(np.abs(local) - h[i], 0.0) ** 2, axis=1)).min()
        # The samples bound the distance from above, by at most half a sample step of the segment.
        step = np.linalg.norm(p1[i] - p0[i]) / 4000
        assert dense - step / 2 - 1e-12 <= d[i] <= dense + 1e-12
    assert np.sum(d == 0.0) > 10 and np.sum(d > 0.0) > 10  # both cases occur
