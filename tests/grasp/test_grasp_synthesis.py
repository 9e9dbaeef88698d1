"""Grasp synthesis: analytic box grasps are antipodal and within the stroke; mesh pairs respect the friction
cone and the family's regions; suction lands on flat faces where the cup fits."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.se3 import random_rotation
from prompose_grasp.grasp import (
    GraspConfig,
    ObjectModel,
    ParallelJawGeometry,
    Plane,
    SuctionCupGeometry,
    antipodal_grasps,
    box_grasps,
    suction_grasps,
)
from prompose_grasp.grasp.parallel_jaw import rim_grasps

R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
JAW = ParallelJawGeometry()
CONFIG = GraspConfig()


def test_box_grasps_are_antipodal_and_within_stroke():
    rng = np.random.default_rng(11)
    for _ in range(10):
        R = random_rotation(rng)
        size = rng.uniform(0.02, 0.15, 3)
        centre = rng.uniform(-0.3, 0.3, 3)
        target = ObjectModel("box", Pose9D(R, centre, size))
        c = box_grasps(target, JAW, CONFIG, Plane.horizontal(-1.0))
        assert len(c) > 0
        narrow = size + 2.0 * CONFIG.min_clearance_m <= JAW.stroke_m
        kept = np.flatnonzero(c.pre_rejected == "")
        # Candidates exist for every axis narrow enough, and none for the others.
        assert bool(len(kept)) == bool(narrow.any())
        for k in kept:
            T = c.T_base_tcp[k]
            np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)  # a rotation
            assert np.linalg.det(T[:3, :3]) > 0
            y_obj = R.T @ T[:3, 1]
            i = int(np.argmax(np.abs(y_obj)))
            np.testing.assert_allclose(np.abs(y_obj[i]), 1.0, atol=1e-12)  # closing along a box axis
            assert narrow[i] and c.opening_m[k] <= JAW.stroke_m + 1e-12
            assert math.isclose(c.width_m[k], size[i], abs_tol=1e-12)
            local = (c.contacts[k] - centre) @ R  # (2, 3) contacts in the object frame
            # On the two opposite faces normal to axis i, inside the face (antipodal with zero friction).
            np.testing.assert_allclose(np.sort(local[:, i]), [-size[i] / 2, size[i] / 2], atol=1e-12)
            others = [a for a in range(3) if a != i]
            assert np.all(np.abs(local[:, others]) <= size[others] / 2 + 1e-12)
            np.testing.assert_allclose(T[:3, 3], c.contacts[k].mean(axis=0), atol=1e-12)  # tcp centred
            # The approach is perpendicular to the closing direction.
            assert abs(T[:3, 2] @ T[:3, 1]) < 1e-12


def test_top_down_box_grasp_is_best_and_centred():
    target = ObjectModel("box", Pose9D(R_UP, [-0.5, 0.0, 0.04], [0.05, 0.08, 0.06]))
    c = box_grasps(target, JAW, CONFIG, Plane.horizontal(0.0))
    best = int(np.argmax(np.where(c.pre_rejected == "", c.quality, -1)))
    np.testing.assert_allclose(c.T_base_tcp[best][:3, 2], [0.0, 0.0, -1.0], atol=1e-12)  # top-down
    np.testing.assert_allclose(c.T_base_tcp[best][:2, 3], [-0.5, 0.0], atol=1e-12)  # over the centre
    # The palm stays palm_clearance above the top face: tcp depth below the top = min(half height, reach).
    depth = 0.04 - c.T_base_tcp[best][2, 3] + 0.04  # top at z = 0.08
    assert math.isclose(depth, min(0.04, JAW.palm_to_tcp_m - CONFIG.palm_clearance_m), abs_tol=1e-12)


def _annulus(r_in, r_out, height, family, centre=(0.0, 0.0, 0.0)):
    mesh = trimesh.creation.annulus(r_min=r_in, r_max=r_out, height=height, sections=64)
    mesh.apply_translation(centre)
    pose = Pose9D(R_UP, centre, [2 * r_out, height, 2 * r_out])
    return ObjectModel(family, pose, mesh=mesh, family=family)


def _inward_normal(p, centre, r_in, r_out, height):
    """Analytic inward normal of an annulus (axis along base z) at a surface point."""
    d = p - centre
    r = math.hypot(d[0], d[1])
    radial = np.array([d[0], d[1], 0.0]) / r
    if abs(abs(d[2]) - height / 2) < 1e-9:
        return np.array([0.0, 0.0, -np.sign(d[2])])
    return -radial if abs(r - r_out) < abs(r - r_in) else radial


@pytest.mark.parametrize(("family", "r_in", "r_out"), [("bowl", 0.07, 0.08), ("mug", 0.03, 0.038)])
def test_antipodal_pairs_in_friction_cone_and_family_region(family, r_in, r_out):
    height = 0.09
    centre = np.array([-0.5, 0.1, height / 2])
    target = _annulus(r_in, r_out, height, family, centre)
    c = antipodal_grasps(target, JAW, CONFIG, Plane.horizontal(0.0))
    assert len(c) > 0
    # A 64-gon deviates from the circle's normal by up to half a sector (2.8 deg).
    cone = math.atan(CONFIG.friction_coefficient) + math.radians(180.0 / 64)
    labels = set()
    for k in range(len(c)):
        p1, p2 = c.contacts[k]
        u = (p2 - p1) / np.linalg.norm(p2 - p1)
        assert np.arccos(np.clip(_inward_normal(p1, centre, r_in, r_out, height) @ u, -1, 1)) <= cone
        assert np.arccos(np.clip(_inward_normal(p2, centre, r_in, r_out, height) @ -u, -1, 1)) <= cone
        assert c.width_m[k] + 2 * CONFIG.min_clearance_m <= JAW.stroke_m + 1e-12
        assert c.opening_m[k] <= JAW.stroke_m + 1e-12
        labels.add(c.reason[k].split(")")[0].split()[-1])
        if family == "bowl":  # by the rim: both contacts in the top band
            assert min(p1[2], p2[2]) >= height - max(0.15 * height, 0.015) - 1e-9
    assert labels <= ({"rim"} if family == "bowl" else {"rim", "body"})


@pytest.mark.parametrize(
    ("family", "r_in", "r_out"), [("bowl", 0.07, 0.08), ("mug", 0.03, 0.038), ("cup", 0.038, 0.04)]
)
def test_rim_grasps_straddle_the_wall_below_the_top(family, r_in, r_out):
    height = 0.09
    centre = np.array([-0.5, 0.1, height / 2])
    target = _annulus(r_in, r_out, height, family, centre)
    c = rim_grasps(target, JAW, CONFIG, Plane.horizontal(0.0))
    assert len(c) == 16 * 3 * 3 * 2 * 2  # angles x depths x tilts x openings x flips
    wall = r_out - r_in
    openings = set()
    for k in range(len(c)):
        T = c.T_base_tcp[k]
        p, y, a = T[:3, 3], T[:3, 1], T[:3, 2]
        d = p - centre
        radial = np.array([d[0], d[1], 0.0]) / math.hypot(d[0], d[1])
        # The closing line is horizontal and radial (rounding only: 1e-9).
        assert abs(y[2]) < 1e-9 and abs(abs(y @ radial) - 1.0) < 1e-9
        # The pads' centre is on the middle of the wall: the rim's 22.5 deg angles fall on vertices of the
        # 64-gon, so the radius is exact (1e-9: rounding).
        assert math.hypot(d[0], d[1]) == pytest.approx((r_in + r_out) / 2.0, abs=1e-9)
        # The pad overlaps the wall but for at most 4 mm: its centre at least half a pad less 4 mm below the
        # top, and the deepest half a pad plus 1 cm.
        assert JAW.pad_size_m[2] / 2 - 0.004 - 1e-12 <= height - p[2] <= JAW.pad_size_m[2] / 2 + 0.01 + 1e-12
        # Top-down or tilted 20 deg about the closing line (1e-9: rounding).
        assert a @ y == pytest.approx(0.0, abs=1e-9)
        assert math.degrees(math.acos(min(1.0, -a[2]))) <= 20.0 + 1e-6
        # The contacts are the wall's two faces, and the jaws open wider than the wall.
        radii = sorted(math.hypot(*(q - centre)[:2]) for q in c.contacts[k])
        np.testing.assert_allclose(radii, [r_in, r_out], atol=1e-9)
        assert wall < c.opening_m[k] <= JAW.stroke_m + 1e-12 and c.width_m[k] == pytest.approx(wall)
        openings.add(round(float(c.opening_m[k]), 9))
    # Two openings: the wall plus the planner's clearance, and plus 25 mm each side (robust to the wall
    # standing that far from the estimate); the wide one ranks first.
    assert openings == {round(wall + 2 * CONFIG.clearance_m, 9), round(wall + 0.05, 9)}
    assert c.opening_m[int(np.argmax(c.quality))] == pytest.approx(wall + 0.05)
    # A container lying on its side has no rim grasps, nor has a bottle.
    lying = ObjectModel(family, Pose9D(np.eye(3), centre, target.pose.size), family=family)
    assert len(rim_grasps(lying, JAW, CONFIG, Plane.horizontal(0.0))) == 0
    bottle = ObjectModel("bottle", target.pose, mesh=target.mesh, family="bottle")
    assert len(rim_grasps(bottle, JAW, CONFIG, Plane.horizontal(0.0))) == 0


def test_suction_on_faces_where_the_cup_fits_and_flat():
    cup = SuctionCupGeometry()
    carton = ObjectModel("carton", Pose9D(R_UP, [0.0, -0.6, 0.13], [0.38, 0.26, 0.24]), family="carton")
    c = suction_grasps(carton, cup, CONFIG, Plane.horizontal(0.0))
    assert len(c) and np.all(c.pre_rejected == "")
    best = int(np.argmax(c.quality))
    np.testing.assert_allclose(c.T_base_tcp[best][:3, 2], [0, 0, -1], atol=1e-12)  # top face, pressing down
    np.testing.assert_allclose(c.T_base_tcp[best][:3, 3], [0.0, -0.6, 0.26], atol=1e-12)  # above the centre
    for T in c.T_base_tcp:  # never from below
        assert T[2, 2] < 0.5 + 1e-12
    # A bottle-like cylinder (radius 20 mm < the 25 mm cup) with its mesh: no face seals.
    mesh = trimesh.creation.cylinder(radius=0.02, height=0.2, sections=48)
    bottle = ObjectModel("bottle", Pose9D(R_UP, [0, 0, 0], [0.04, 0.2, 0.04]), mesh=mesh, family="bottle")
    c2 = suction_grasps(bottle, cup, CONFIG, Plane.horizontal(-0.1))
    assert np.all(c2.pre_rejected != "")
    # A heavy carton is refused for payload (118 N over a safety factor 2 holds 6 kg top-down).
    heavy = ObjectModel("carton", carton.pose, family="carton", mass_kg=9.0)
    assert set(suction_grasps(heavy, cup, CONFIG, Plane.horizontal(0.0)).pre_rejected) == {"payload"}


def test_suction_on_a_stepped_carton_seals_on_the_flat_top_near_its_centre_of_mass():
    # A 30 x 20 x 15 cm carton with its last 10 cm 5 cm lower (two closed boxes side by side): the estimated
    # box is the full 30 x 20 x 15 cm, but its top face is flat only over the first 20 cm, and the centre of
    # mass (uniform density) sits 12.5 mm towards the tall part: x = (0.006 * -0.05 + 0.002 * 0.10) / 0.008.
    tall = trimesh.creation.box(extents=[0.2, 0.2, 0.15])
    tall.apply_translation([-0.05, 0.0, 0.075])
    low = trimesh.creation.box(extents=[0.1, 0.2, 0.10])
    low.apply_translation([0.10, 0.0, 0.05])
    mesh = trimesh.util.concatenate([tall, low])
    mesh.apply_translation([0.0, -0.6, 0.0])
    carton = ObjectModel(
        "carton", Pose9D(R_UP, [0.0, -0.6, 0.075], [0.3, 0.15, 0.2]), mesh=mesh, family="carton"
    )
    np.testing.assert_allclose(carton.centre_of_mass, [-0.0125, -0.6, 0.0625 + 0.00625], atol=1e-9)
    cup = SuctionCupGeometry()
    cfg = GraspConfig(suction_grid=5)
    c = suction_grasps(carton, cup, cfg, Plane.horizontal(0.0))
    top = np.flatnonzero(c.T_base_tcp[:, 2, 2] < -1 + 1e-9)  # pressing straight down on the top face
    ok = top[c.pre_rejected[top] == ""]
    assert len(ok) and len(top) > len(ok)
    x = c.T_base_tcp[:, 0, 3]
    # Sealing positions keep the whole 25 mm cup over the tall part (x <= 0.05 - 0.025), up to the sample
    # spacing of the flatness test (2 x sqrt(area / samples) ~ 2.4 cm here).
    assert np.all(x[ok] <= 0.025 + 0.025)
    assert np.all(x[top[c.pre_rejected[top] == "suction_not_flat"]] > 0.025)
    best = ok[np.argmax(c.quality[ok])]
    np.testing.assert_allclose(c.T_base_tcp[best][:3, 3], [-0.0125, -0.6, 0.15], atol=1e-12)  # above the COM


@pytest.mark.parametrize("pairs", [7, 60])
def test_antipodal_pairs_are_the_best_of_all_pairs(pairs):
    # Independent reference: every pair of the same surface samples tested and scored one by one (the
    # module's quality: 0.35 friction margin + 0.25 centring + 0.1 width); the generator must keep the same
    # best pairs in the same order.
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    mesh.apply_translation([-0.4, 0.1, 0.03])
    target = ObjectModel("ball", Pose9D(np.eye(3), [-0.4, 0.1, 0.03], [0.06, 0.06, 0.06]), mesh=mesh)
    cfg = GraspConfig(mesh_samples=120, antipodal_pairs=pairs)
    c = antipodal_grasps(target, JAW, cfg, Plane.horizontal(0.0))
    P, f = trimesh.sample.sample_surface(mesh, cfg.mesh_samples, seed=cfg.seed)
    N = mesh.face_normals[f]
    mu = math.atan(cfg.friction_coefficient)
    com = target.centre_of_mass
    scored = []
    for i in range(len(P)):
        for j in range(i + 1, len(P)):
            d = P[j] - P[i]
            dist = float(np.linalg.norm(d))
            if dist <= 1e-3 or dist + 2 * cfg.min_clearance_m > JAW.stroke_m:
                continue
            u = d / dist
            c1, c2 = -N[i] @ u, N[j] @ u
            if min(c1, c2) < math.cos(mu):
                continue
            w = com - 0.5 * (P[i] + P[j])
            off = np.linalg.norm(w - (w @ u) * u)
            q = 0.35 * (1 - math.acos(min(1.0, min(c1, c2))) / mu) + 0.25 * max(0.0, 1 - off / 0.06)
            scored.append((-(q + 0.1 * (1 - dist / JAW.stroke_m)), i, j))
    best = sorted(scored)[:pairs]  # ties: row-major order, as the generator's stable sort
    rows_per_pair = 2 * len(cfg.antipodal_approaches_deg)
    got = c.contacts[::rows_per_pair]
    assert len(got) == len(best)
    np.testing.assert_allclose(got, [[P[i], P[j]] for _, i, j in best], atol=1e-12)


def test_a_carton_whose_mesh_is_its_box_seals_everywhere_the_cup_fits():
    # The prior's mesh is the estimated box itself: every face is flat all over, as for the box alone.
    R = random_rotation(np.random.default_rng(2))
    size = np.array([0.3, 0.2, 0.25])
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_transform(
        np.block([[R, np.array([[0.1], [-0.5], [0.2]])], [np.zeros((1, 3)), np.ones((1, 1))]])
    )
    pose = Pose9D(R, [0.1, -0.5, 0.2], size)
    cup = SuctionCupGeometry()
    with_mesh = suction_grasps(ObjectModel("c", pose, mesh=mesh), cup, CONFIG, Plane.horizontal(-1.0))
    box_only = suction_grasps(ObjectModel("c", pose), cup, CONFIG, Plane.horizontal(-1.0))
    assert len(with_mesh) == len(box_only) > 0 and np.all(with_mesh.pre_rejected == "")
    # The same poses (the mesh's centre of mass differs from the box centre by rounding, which may reorder
    # grid points at equal distance from it): compare as sorted sets, to 1e-9 m.
    a, b = (np.round(c.T_base_tcp.reshape(len(c), -1), 9) for c in (with_mesh, box_only))
    np.testing.assert_allclose(a[np.lexsort(a.T)], b[np.lexsort(b.T)], atol=2e-9)
