"""The MuJoCo stand-in: scenes, RGB-D cameras with sensor noise, the simulated arm and grippers.

`sim` uses `prompose_grasp`; the library never imports `sim`.

What is here (docs/sim.md has the details):

- `sim.objects`: a procedural object library (box, carton, can, bottle, bowl, mug, cup, laptop, camera, ball,
  tube, sack, parcel) in canonical frames with exact 9-DoF sizes, and meshes from OBJ/STL files.
- `sim.scene_builder`: `SceneBuilder` (one `mujoco.MjSpec`: floor, table, bin, conveyor, EUR pallet, objects,
  cameras, lights, mount bodies); `sim.world`: the compiled `SimWorld` (step, reset, settle, render, ground
  truth); `sim.appearance` (colours, textures, random looks), `sim.placement` (upright, apart).
- `sim.camera`, `sim.noise`: MuJoCo's exact pinhole intrinsics, OpenCV camera frames, depth-sensor noise
  presets ("clean", "realsense", "kinect").
- `sim.robot_scene`, `sim.arm`, `sim.grippers`: the UR arm of the robot layer in the scene (`add_robot`),
  `SimArm` (an `Arm`), `ParallelJawGripper` and `SuctionGripper` (`Gripper`s); `SimCamera` (an `RGBDCamera`
  returning the library's `RGBDFrame`).
- `sim.scene_file`: YAML/JSON scenario files; `sim/scenes/` holds the tabletop, bin and logistics scenes.
- `python -m sim view --scene FILE --out img.png`; `python -m sim.dataset --out DIR ...` (synthetic data).

Rendering is headless: MUJOCO_GL defaults to "egl" (set before MuJoCo loads; EGL through Mesa works on a
CPU-only machine). Set MUJOCO_GL=osmesa where EGL is missing.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from prompose_grasp.robot.interfaces import RGBDFrame
from sim.appearance import Appearance
from sim.arm import SimArm
from sim.camera import CameraSpec, SimCamera, look_at, mujoco_intrinsics
from sim.grippers import ParallelJawGripper, SuctionGripper
from sim.noise import NOISE_PRESETS, DepthNoiseConfig, apply_depth_noise, noise_preset
from sim.objects import FAMILIES, ObjectAsset, load_mesh_object, make_object
from sim.placement import upright_pose
from sim.robot_scene import add_robot
from sim.scene_builder import SceneBuilder
from sim.scene_file import build_scene, load_scene, load_world
from sim.world import SimWorld, Support

__all__ = [
    "FAMILIES",
    "NOISE_PRESETS",
    "Appearance",
    "CameraSpec",
    "DepthNoiseConfig",
    "ObjectAsset",
    "ParallelJawGripper",
    "RGBDFrame",
    "SceneBuilder",
    "SimArm",
    "SimCamera",
    "SimWorld",
    "SuctionGripper",
    "Support",
    "add_robot",
    "apply_depth_noise",
    "build_scene",
    "load_mesh_object",
    "load_scene",
    "load_world",
    "look_at",
    "make_object",
    "mujoco_intrinsics",
    "noise_preset",
    "upright_pose",
]
