"""A tabletop scene for the grounding tests: distinct colours, two identical cups either side of a bowl."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

_CUP = {"bottom_radius_m": 0.025, "top_radius_m": 0.038, "height_m": 0.09}

#: (name, family, params, rgb, (x, y) on the table [m], yaw [rad])
OBJECTS = (
    ("can", "can", {"radius_m": 0.033, "height_m": 0.12}, (0.9, 0.8, 0.1), (-0.24, 0.10), 0.0),
    ("mug", "mug", {"radius_m": 0.042, "height_m": 0.095}, (0.8, 0.1, 0.1), (-0.02, 0.17), 0.4),
    ("box", "box", {"width_m": 0.18, "height_m": 0.25, "depth_m": 0.07}, (0.15, 0.3, 0.85), (0.25, 0.15),
     0.3),
    ("bowl", "bowl", {"radius_m": 0.08, "height_m": 0.05}, (0.15, 0.6, 0.2), (0.03, -0.04), 0.0),
    ("ball", "ball", {"radius_m": 0.028}, (0.95, 0.5, 0.1), (-0.08, -0.20), 0.0),
    ("cup_left", "cup", _CUP, (0.55, 0.2, 0.75), (-0.16, -0.05), 0.0),
    ("cup_right", "cup", _CUP, (0.55, 0.2, 0.75), (0.22, -0.06), 0.0),
)  # fmt: skip


@dataclass(frozen=True)
class SceneFrame:
    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: object
    gt_mask: np.ndarray  # (H, W) instance ids: tests only
    ids: dict[str, int]  # object name -> instance id
    up_cam: np.ndarray  # table normal (world +z) in the camera frame
    gt_poses: dict  # object name -> ground-truth Pose9D in the camera frame: tests only


def render_scene(width: int = 640, height: int = 480, seed: int = 0) -> SceneFrame:
    return _render_table_scene("grounding_test", OBJECTS, width, height, seed)


def _render_table_scene(scene_name: str, objects, width: int, height: int, seed: int) -> SceneFrame:
    """The 1.2 x 0.8 m table with `objects` (name, family, params, rgb, (x, y), yaw) on it, seen by a
    RealSense-like front camera."""
    from sim import NOISE_PRESETS, Appearance, CameraSpec, SceneBuilder, look_at, make_object, upright_pose

    b = SceneBuilder(scene_name)
    b.add_floor()
    b.add_skybox()
    b.add_light([0.5, -0.5, 2.5])
    table = b.add_table(size_xy_m=(1.2, 0.8), height_m=0.75)
    ids = {}
    for name, family, params, rgb, xy, yaw in objects:
        asset = make_object(family, params)
        info = b.add_object(
            asset, name, upright_pose(asset, table, xy, yaw), appearance=Appearance(rgba=(*rgb, 1))
        )
        ids[name] = info.instance_id
    cam = CameraSpec(
        "front",
        width,
        height,
        58.0,
        look_at([0.0, -0.75, 1.25], [0.0, 0.0, 0.75]),
        noise=NOISE_PRESETS["realsense"],
    )
    b.add_camera(cam)
    with b.build() as world:
        world.settle()
        frame = world.render("front", rng=np.random.default_rng(seed))
        gt = world.ground_truth_mask("front")
        up_cam = world.T_world_cam("front")[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        poses = {g.name: g.as_pose9d() for g in world.ground_truth("front")}
    return SceneFrame(frame.rgb, frame.depth_m, frame.intrinsics, gt, ids, up_cam, poses)


#: A wall standing across the back of the table (taller than the camera), a grey box of the wall's colour
#: leaning on it, and a red mug in front: (name, family, params, rgb, (x, y) [m], yaw [rad]).
WALL_OBJECTS = (
    ("wall", "box", {"width_m": 1.1, "height_m": 0.75, "depth_m": 0.04}, (0.6, 0.6, 0.6), (0.0, 0.30), 0.0),
    ("box", "box", {"width_m": 0.16, "height_m": 0.2, "depth_m": 0.06}, (0.62, 0.6, 0.58), (0.05, 0.249),
     0.0),
    ("mug", "mug", {"radius_m": 0.042, "height_m": 0.095}, (0.8, 0.1, 0.1), (-0.2, 0.0), 0.4),
)  # fmt: skip


def render_wall_scene(width: int = 640, height: int = 480, seed: int = 0) -> SceneFrame:
    """The table of `render_scene` with `WALL_OBJECTS` on it, seen by the same camera."""
    return _render_table_scene("grounding_wall_test", WALL_OBJECTS, width, height, seed)


#: Look-alikes that only object knowledge tells apart: three grey cans of real products' sizes (a tuna can,
#: a 12 oz soda can, a large coffee can) and three bottles of one size and shape in the colours of a mustard,
#: a ketchup and a bleach bottle. (name, family, params, rgb, (x, y) [m], yaw [rad]).
SIZE_ONLY_CANS = (
    ("tuna", "can", {"radius_m": 0.0425, "height_m": 0.040}, (0.55, 0.55, 0.57), (-0.25, 0.02), 0.0),
    ("soda", "can", {"radius_m": 0.033, "height_m": 0.122}, (0.55, 0.55, 0.57), (0.0, 0.05), 0.0),
    ("coffee", "can", {"radius_m": 0.0655, "height_m": 0.17}, (0.55, 0.55, 0.57), (0.25, 0.02), 0.0),
)  # fmt: skip
#: Three grey boxes standing, of a cereal box's, a cracker box's and a sugar box's sizes (the YCB packs'):
#: "cereal box" is a name of the box family too, whose typical box is a cracker box's size.
SIZE_ONLY_BOXES = (
    ("cereal", "box", {"width_m": 0.2, "height_m": 0.3, "depth_m": 0.07}, (0.55, 0.55, 0.57), (0.25, 0.08),
     0.2),
    ("cracker", "box", {"width_m": 0.158, "height_m": 0.21, "depth_m": 0.06}, (0.55, 0.55, 0.57),
     (-0.02, 0.05), -0.2),
    ("sugar", "box", {"width_m": 0.089, "height_m": 0.175, "depth_m": 0.038}, (0.55, 0.55, 0.57),
     (-0.26, 0.02), 0.3),
)  # fmt: skip
_BOTTLE = {"radius_m": 0.032, "height_m": 0.19, "neck_ratio": 0.4, "shoulder_ratio": 0.6}
COLOUR_ONLY_BOTTLES = (
    ("mustard", "bottle", _BOTTLE, (0.9, 0.78, 0.1), (0.22, 0.0), 0.0),
    ("ketchup", "bottle", _BOTTLE, (0.8, 0.1, 0.08), (-0.22, 0.02), 0.0),
    ("bleach", "bottle", _BOTTLE, (0.93, 0.93, 0.93), (0.0, 0.1), 0.0),
)  # fmt: skip


def render_objects(
    scene_name: str, objects, width: int = 640, height: int = 480, seed: int = 0
) -> SceneFrame:
    """The table of `render_scene` with `objects` ((name, family, params, rgb, (x, y) [m], yaw)) on it."""
    return _render_table_scene(scene_name, objects, width, height, seed)


def render_lookalikes(objects, width: int = 640, height: int = 480, seed: int = 0) -> SceneFrame:
    """The table of `render_scene` with look-alike `objects` (`SIZE_ONLY_CANS`, `COLOUR_ONLY_BOTTLES`)."""
    return _render_table_scene("grounding_lookalikes_test", objects, width, height, seed)
