"""World builder, scenario files and ground truth consistent with the rendered images."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import back_project
from scipy.spatial import Delaunay

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.boxes import box_corners
from sim.appearance import random_appearance
from sim.camera import CameraSpec, look_at
from sim.noise import NOISE_PRESETS
from sim.objects import make_object
from sim.placement import sample_upright_placements
from sim.scene_builder import EUR_PALLET_SIZE_M, SceneBuilder
from sim.scene_file import build_scene, load_scene, parse_scene

pytestmark = pytest.mark.sim

SCENES = sorted((Path(__file__).parents[2] / "sim" / "scenes").glob("*.yaml"))


def _tabletop(noise: str, rng, families=("mug", "can", "bottle", "bowl", "laptop", "camera", "box", "ball")):
    b = SceneBuilder("gt")
    b.add_floor()
    table = b.add_table(size_xy_m=(1.6, 1.1))
    b.add_light([0.3, -0.4, 2.5])
    assets = [make_object(f, rng=rng) for f in families]
    poses = sample_upright_placements(assets, table, rng, clearance_m=0.001)
    for a, T in zip(assets, poses):
        b.add_object(a, a.category, T, appearance=random_appearance(rng))
    T_world_cam = look_at([0.3, -1.0, 1.7], [0.0, 0.0, 0.76])
    b.add_camera(CameraSpec("cam", 320, 240, 60.0, T_parent_cam=T_world_cam, noise=NOISE_PRESETS[noise]))
    world = b.build()
    world.settle()
    return world


@pytest.mark.parametrize("noise", ["clean", "realsense", "kinect"])
def test_ground_truth_consistent_with_images(noise, rng):
    """Back-projected depth inside each mask lies in its GT box; the projected box encloses the mask."""
    with _tabletop(noise, rng) as world:
        frame = world.render("cam", rng=rng)
        mask = world.ground_truth_mask("cam")
        K = frame.intrinsics
        cfg = NOISE_PRESETS[noise]
        seen = 0
        for gt in world.ground_truth("cam"):
            m = mask == gt.instance_id
            if m.sum() < 20:
                continue
            pts = back_project(frame.depth_m, K.fx, K.fy, K.cx, K.cy, m)
            if noise == "clean":
                assert len(pts) == m.sum()  # every object pixel has a reading without noise
            if len(pts) == 0:  # edge dropout can swallow a small, far object whole
                continue
            seen += 1
            # noise is axial: a point moves along its ray by at most error_bound(z) (5 sigma + half a unit);
            # 1e-4 m covers the clean depth buffer's precision (1e-7 m) and tessellation on the box faces
            ray = pts / pts[:, 2:3]
            bound = cfg.error_bound_m(pts[:, 2])[:, None] * ray + 1e-4
            p_obj = (pts - gt.t_cam_obj_m) @ gt.R_cam_obj
            d_obj = np.abs(bound @ gt.R_cam_obj)  # bound per object axis
            assert np.all(np.abs(p_obj) <= gt.size_m / 2.0 + np.abs(d_obj).max(axis=1, keepdims=True)), (
                gt.name
            )
            corners = box_corners(gt.size_m) @ gt.R_cam_obj.T + gt.t_cam_obj_m
            uv = corners[:, :2] / corners[:, 2:] * [K.fx, K.fy] + [K.cx, K.cy]
            v, u = np.nonzero(m)
            # pixel centres of the mask inside the projected box's hull, allowing the half-pixel footprint
            hull = Delaunay(uv)
            inside = np.zeros(len(u), bool)
            for du, dv in ((0, 0), (0.5, 0.5), (-0.5, 0.5), (0.5, -0.5), (-0.5, -0.5)):
                inside |= hull.find_simplex(np.stack([u + du, v + dv], 1).astype(float)) >= 0
            assert inside.all(), gt.name
        assert seen >= 4


def test_clean_depth_points_touch_the_boxes(rng):
    """Clean depth: every visible object has surface points on its box faces (the box is tight)."""
    with _tabletop("clean", rng, families=("can", "box", "bowl")) as world:
        _, depth = world.render_clean("cam")
        mask = world.ground_truth_mask("cam")
        K = world.intrinsics("cam")
        for gt in world.ground_truth("cam"):
            pts = back_project(depth, K.fx, K.fy, K.cx, K.cy, mask == gt.instance_id)
            p_obj = (pts - gt.t_cam_obj_m) @ gt.R_cam_obj
            # the top face (+y) is seen from above: a point reaches it within 2 mm (pixel footprint ~1.5 mm)
            assert p_obj[:, 1].max() == pytest.approx(gt.size_m[1] / 2.0, abs=2e-3), gt.name


def test_objects_rest_upright_after_settling(rng):
    with _tabletop("clean", rng, families=("can", "box", "bottle", "mug")) as world:
        table_z = world.supports["table"].top_z_m
        for o in world.objects:
            T = world.T_world_obj(o.name)
            assert T[2, 1] > 0.999  # canonical +y still points up: nothing fell over
            assert T[2, 3] - o.size[1] / 2.0 == pytest.approx(table_z, abs=2e-3)  # 2 mm: contact softness


def test_pallet_is_eur_sized():
    b = SceneBuilder("pallet")
    b.add_floor()
    pallet = b.add_pallet()
    with b.build() as world:
        geoms = [
            world.model.geom(i)
            for i in range(world.model.ngeom)
            if world.model.geom(i).name.startswith("pallet")
        ]
        lo = np.min(
            [
                world.data.geom_xpos[g.id]
                - np.abs(world.data.geom_xmat[g.id].reshape(3, 3)) @ world.model.geom_size[g.id]
                for g in geoms
            ],
            axis=0,
        )
        hi = np.max(
            [
                world.data.geom_xpos[g.id]
                + np.abs(world.data.geom_xmat[g.id].reshape(3, 3)) @ world.model.geom_size[g.id]
                for g in geoms
            ],
            axis=0,
        )
        np.testing.assert_allclose(hi - lo, EUR_PALLET_SIZE_M, atol=1e-9)
        assert pallet.top_z_m == pytest.approx(0.144)
        assert len(geoms) == 3 + 9 + 3 + 5  # bottom boards, blocks, cross boards, deck boards


@pytest.mark.slow
@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scenario_loads_resets_steps_and_renders(path):
    spec = load_scene(path)
    with build_scene(spec) as world:
        assert len(world.objects) >= 2 and world.cameras and world.place_targets
        start = world.data.qpos.copy()
        world.step(1000)
        assert world.is_finite()
        world.reset()
        if world.robot is not None:  # the arm resets to its home configuration
            np.testing.assert_array_equal(world.data.qpos[world.robot.qpos_adr], world.robot.home_q)
        free = [world.model.jnt_qposadr[world.model.body_jntadr[o.body_id]] for o in world.objects]
        for adr in free:  # every object back where it was added
            np.testing.assert_array_equal(world.data.qpos[adr : adr + 7], world.model.qpos0[adr : adr + 7])
        world.step(1000)
        assert world.is_finite() and start.shape == world.data.qpos.shape
        rng = np.random.default_rng(0)
        for cam in world.cameras:
            spec_c = world.cameras[cam]
            frame = world.render(cam, rng=rng)
            assert frame.rgb.shape == (spec_c.height, spec_c.width, 3) and frame.rgb.dtype == np.uint8
            assert frame.depth_m.shape == (spec_c.height, spec_c.width) and frame.depth_m.dtype == np.float32
            assert np.isfinite(frame.depth_m).all() and (frame.depth_m > 0).mean() > 0.2
            assert frame.rgb.std() > 5  # not a blank image


def _doc(**over):
    doc = {
        "version": 1,
        "name": "t",
        "supports": [{"name": "table", "type": "table"}],
        "cameras": [
            {"name": "c", "pose": {"pos": [0, -1, 1.5], "look_at": [0, 0, 0.75]}, "width": 64, "height": 48}
        ],
        "objects": [{"name": "a", "mesh": {"family": "can"}, "place": {"support": "table"}}],
    }
    doc.update(over)
    return doc


def test_scene_file_errors_name_the_choices(tmp_path):
    with pytest.raises(UnknownNameError, match="ur5e"):
        parse_scene(_doc(robot={"model": "ur6e"}))
    with pytest.raises(UnknownNameError, match="suction"):
        parse_scene(_doc(gripper={"type": "magnet"}))
    with pytest.raises(UnknownNameError, match="mug"):
        parse_scene(
            _doc(objects=[{"name": "a", "mesh": {"family": "teapot"}, "place": {"support": "table"}}])
        )
    with pytest.raises(UnknownNameError, match="objects"):
        parse_scene(_doc(objcts=[]))
    with pytest.raises(UnknownNameError, match="kinect"):
        parse_scene(_doc(cameras=[{"name": "c", "pose": {"pos": [0, 0, 1]}, "noise": "lidar"}]))
    with pytest.raises(UnknownNameError, match="pallet"):
        parse_scene(_doc(supports=[{"name": "s", "type": "shelf"}]))
    with pytest.raises(InvalidInputError, match="exactly one of pose, place, stack"):
        parse_scene(_doc(objects=[{"name": "a", "mesh": {"family": "can"}}]))
    with pytest.raises(InvalidInputError, match="does not exist"):
        load_scene(tmp_path / "nope.yaml")


def test_json_scene_with_mesh_file_builds(tmp_path, rng):
    import trimesh

    trimesh.creation.box(extents=[0.05, 0.08, 0.03]).export(tmp_path / "block.stl")
    doc = _doc(
        objects=[
            {"name": "blk", "prompt": "grey block", "mesh": "block.stl", "scale": 2.0,
             "rgba": [0.5, 0.5, 0.5, 1], "pose": {"pos": [0.0, 0.0, 0.84], "rpy_deg": [90, 0, 0]}},
            {"name": "can", "mesh": {"family": "can", "params": {"radius_m": 0.03}},
             "place": {"support": "table"}},
        ],
        robot={"model": "ur5e"},
        gripper={"type": "parallel_jaw"},
    )  # fmt: skip
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    with build_scene(load_scene(path), settle=False) as world:
        blk = world.object("blk")
        np.testing.assert_allclose(blk.size, [0.10, 0.16, 0.06], atol=1e-9)
        assert blk.prompt == "grey block"
        np.testing.assert_allclose(world.T_world_obj("blk")[:3, 3], [0.0, 0.0, 0.84], atol=1e-9)
        assert world.object("can").size[0] == pytest.approx(0.06)
