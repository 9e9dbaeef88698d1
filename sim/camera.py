"""Simulated RGB-D cameras: MuJoCo's projection as `CameraIntrinsics`, frame conversions, the frame type.

Frames. `cam` is OpenCV (x right, y down, z forward). A MuJoCo camera (`camgl` here) looks along its -z with
+y up, so the two differ by a half turn about x: `T_camgl_cam = diag(1, -1, -1, 1)`, and `T_world_cam =
T_world_camgl @ T_camgl_cam`.

Projection. MuJoCo renders with a vertical field of view `fovy` and square pixels, and its image rows run top
to bottom after the renderer's flip. With OpenCV's convention that pixel (u, v) has its centre at integer (u,
v):

    fy = fx = (height / 2) / tan(fovy / 2),   cx = (width - 1) / 2,   cy = (height - 1) / 2

(the principal point sits at the centre of the image, which is half a pixel off the integer grid for even
sizes). Depth from `mujoco.Renderer` with depth rendering on is the metric distance along the optical axis (z
in `cam`), not along the ray. Both facts are checked numerically in tests/sim/test_sim_camera.py against a
rendered plane at a known pose (error below 1e-6 m).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import CameraError, InvalidInputError, UnknownNameError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import as_transform, make_T
from prompose_grasp.robot.interfaces import RGBDCamera, RGBDFrame
from sim.noise import NOISE_PRESETS, DepthNoiseConfig

__all__ = [
    "T_CAMGL_CAM",
    "CameraSpec",
    "RendersCameras",
    "SimCamera",
    "look_at",
    "mujoco_intrinsics",
]

#: (4, 4) OpenCV camera frame expressed in the MuJoCo camera frame (half turn about x); its own inverse.
T_CAMGL_CAM = np.diag([1.0, -1.0, -1.0, 1.0])
T_CAMGL_CAM.setflags(write=False)


def mujoco_intrinsics(width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
    """Pinhole intrinsics [px] of a MuJoCo camera rendering width x height with vertical view angle fovy."""
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise InvalidInputError(f"width and height must be positive integers, got {width} x {height}")
    if not (math.isfinite(fovy_deg) and 0.0 < fovy_deg < 180.0):
        raise InvalidInputError(f"fovy_deg must lie in (0, 180) degrees, got {fovy_deg}")
    # The library's from_fovy implements exactly MuJoCo's projection; tests/sim checks it against renders.
    return CameraIntrinsics.from_fovy(int(width), int(height), float(fovy_deg))


def look_at(eye_m: ArrayLike, target_m: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam (4, 4) of an OpenCV camera at `eye_m` (3,) [m] looking at `target_m` (3,) [m].

    The image's "up" (-y of the camera) leans towards the world vector `up`.
    """
    eye = np.asarray(eye_m, dtype=np.float64)
    target = np.asarray(target_m, dtype=np.float64)
    up_v = np.asarray(up, dtype=np.float64)
    if eye.shape != (3,) or target.shape != (3,) or up_v.shape != (3,):
        raise InvalidInputError("look_at needs (3,) eye, target and up vectors")
    z = target - eye
    if not np.all(np.isfinite(z)) or np.linalg.norm(z) < 1e-9:
        raise InvalidInputError(f"look_at: eye {eye} and target {target} must be finite and distinct")
    z /= np.linalg.norm(z)
    x = np.cross(z, up_v)
    if np.linalg.norm(x) < 1e-9:
        raise InvalidInputError("look_at: the viewing direction is parallel to `up`; pass another up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), eye)


@dataclass(frozen=True, eq=False)
class CameraSpec:
    """A camera to add to a scene.

    Attributes:
        name: unique camera name.
        width, height: image size [px].
        fovy_deg: vertical field of view [deg] (MuJoCo's convention).
        T_parent_cam: (4, 4) pose of the OpenCV camera frame in the parent body frame (world if fixed).
        parent_body: None for a fixed camera on the world body; a body name for a mounted (wrist) camera.
        noise: depth sensor model applied by `SimWorld.render`.
    """

    name: str
    width: int = 640
    height: int = 480
    fovy_deg: float = 58.0
    T_parent_cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    parent_body: str | None = None
    noise: DepthNoiseConfig = NOISE_PRESETS["clean"]

    def __post_init__(self) -> None:
        if not self.name:
            raise InvalidInputError("a camera needs a non-empty name")
        mujoco_intrinsics(self.width, self.height, self.fovy_deg)  # validates size and fovy
        object.__setattr__(self, "T_parent_cam", as_transform(self.T_parent_cam, name="T_parent_cam"))

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return mujoco_intrinsics(self.width, self.height, self.fovy_deg)


class RendersCameras(Protocol):
    """What a `SimCamera` needs of the world it looks at (`sim.world.SimWorld` is one): its cameras by name,
    their intrinsics, and a render of the current state."""

    @property
    def cameras(self) -> Mapping[str, CameraSpec]: ...

    def intrinsics(self, camera: str) -> CameraIntrinsics: ...

    def render(self, camera: str, *, rng: np.random.Generator | None = None) -> RGBDFrame: ...


class SimCamera(RGBDCamera):
    """A camera of a `SimWorld` as an `RGBDCamera` device: `capture()` renders the current sim state.

    Frames are the library's `RGBDFrame` with the camera's noise model applied, `timestamp_s` the sim time
    and `T_base_cam` the camera pose in the arm's base frame (the world frame when the scene has no arm);
    wrist cameras follow the flange. `rng` draws the sensor noise; it is required unless the camera is clean.

    >>> with SimCamera(world, "front", rng=np.random.default_rng(0)) as cam:  # doctest: +SKIP
    ...     frame = cam.capture()
    """

    def __init__(self, world: RendersCameras, name: str, rng: np.random.Generator | None = None):
        if name not in world.cameras:
            raise UnknownNameError("camera", name, sorted(world.cameras))
        spec = world.cameras[name]
        if spec.noise != DepthNoiseConfig(name=spec.noise.name) and rng is None:
            raise InvalidInputError(
                f"camera {name!r} uses noise model {spec.noise.name!r}: pass a seeded rng"
            )
        self.world = world
        self.name = name
        self.rng = rng

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.world.intrinsics(self.name)

    def capture(self) -> RGBDFrame:
        """Render the camera now (no time passes); raises `CameraError` when the renderer fails."""
        self._require()
        try:
            return self.world.render(self.name, rng=self.rng)
        except Exception as exc:  # an OpenGL/EGL failure should surface as the library's camera error
            raise CameraError(f"sim camera {self.name!r} could not render: {exc}") from exc
