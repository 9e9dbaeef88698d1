"""The compiled scene: `SimWorld` holds the MuJoCo model and data, the named objects, supports and cameras,
and the renderers; `Support`, `ObjectInfo` and `ObjectGroundTruth` are what it knows of them.

Frames: `world` is MuJoCo's world (z up, metres). A support's `T_world_surface` has its origin at the centre
of the top surface, z up. An object body frame is the object's canonical frame (origin at the amodal box
centre, +y the object's up), so `T_world_obj` is the body pose and ground truth needs no offsets. Cameras use
OpenCV frames (`sim.camera`). `sim.scene_builder.SceneBuilder` builds a `SimWorld`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import (
    as_transform,
    invert_T,
    make_T,
    quat_wxyz_from_R,
)
from prompose_grasp.robot.interfaces import RGBDFrame
from sim.camera import T_CAMGL_CAM, CameraSpec
from sim.noise import DepthNoiseConfig, apply_color_noise, apply_depth_noise

__all__ = ["ObjectGroundTruth", "ObjectInfo", "SimWorld", "Support"]

log = logging.getLogger(__name__)

#: Depth readings at or beyond this fraction of the far clipping plane are background, not geometry.
_FAR_FRACTION = 0.999


@dataclass(frozen=True, eq=False)
class Support:
    """A surface objects can stand on or be placed onto.

    Attributes:
        name: unique name ("table").
        kind: "table", "bin", "conveyor", "pallet" or "floor".
        T_world_surface: (4, 4) frame at the centre of the top (standing) surface, z up [m].
        half_extents_xy_m: (2,) half size of the usable surface along its x and y [m].
        wall_height_m: height of walls above the surface (bins), else 0 [m].
    """

    name: str
    kind: str
    T_world_surface: np.ndarray
    half_extents_xy_m: np.ndarray
    wall_height_m: float = 0.0

    @property
    def top_z_m(self) -> float:
        """Height of the standing surface in the world [m]."""
        return float(self.T_world_surface[2, 3])


@dataclass(frozen=True, eq=False)
class ObjectInfo:
    """What the world knows about one object (metadata; its pose comes from `SimWorld.T_world_obj`)."""

    name: str
    instance_id: int
    category: str
    prompt: str
    size: np.ndarray
    symmetry: str
    source: str
    params: dict
    body_id: int = -1
    visual_geom_ids: tuple[int, ...] = ()


@dataclass(frozen=True, eq=False)
class ObjectGroundTruth:
    """Ground-truth 9-DoF box of one object in a camera frame (tests, dataset generation, benchmarks only).

    Attributes:
        R_cam_obj: (3, 3) rotation from the object's canonical frame to the OpenCV camera frame.
        t_cam_obj_m: (3,) centre of the amodal box in the camera frame [m].
        size_m: (3,) full extents along the object's axes [m].
    """

    name: str
    instance_id: int
    category: str
    prompt: str
    R_cam_obj: np.ndarray
    t_cam_obj_m: np.ndarray
    size_m: np.ndarray
    symmetry: str
    source: str
    params: dict

    def as_pose9d(self):
        """The box as the library's `Pose9D` (R, t, size)."""
        from prompose_grasp.geometry import Pose9D

        return Pose9D(R=self.R_cam_obj, t=self.t_cam_obj_m, size=self.size_m)


class SimWorld:
    """A compiled scene: MuJoCo model and data, named objects, supports, cameras, and renderers.

    Use as a context manager (or call `close`) to release the OpenGL contexts of the renderers.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        objects: Iterable[ObjectInfo],
        cameras: dict[str, CameraSpec],
        supports: dict[str, Support],
        place_targets: dict[str, Support],
        robot=None,
    ):
        self.model = model
        self.data = mujoco.MjData(model)
        #: `sim.robot_scene.RobotInfo` of the arm and gripper, or None for a scene without a robot.
        self.robot = robot
        self._step_hooks: list[Callable[[SimWorld], None]] = []
        self.objects: tuple[ObjectInfo, ...] = tuple(objects)
        self.cameras = cameras
        self.supports = supports
        self.place_targets = place_targets
        self._by_name = {o.name: o for o in self.objects}
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._geom_instance = np.zeros(model.ngeom + 1, dtype=np.int32)  # last slot: background (-1)
        for o in self.objects:
            self._geom_instance[list(o.visual_geom_ids)] = o.instance_id
        if self.robot is not None:
            self.robot.apply_home(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    # --------------------------------------------------------------------------------------------------------
    # simulation

    def reset(self) -> None:
        """Back to the initial state (objects where they were added, the arm at home, time 0)."""
        mujoco.mj_resetData(self.model, self.data)
        if self.robot is not None:
            self.robot.apply_home(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance `n` physics steps of `model.opt.timestep` seconds (running the step hooks after each)."""
        if n < 0:
            raise InvalidInputError(f"n must be >= 0, got {n}")
        if not n:
            return
        if not self._step_hooks:
            mujoco.mj_step(self.model, self.data, nstep=int(n))
            return
        for _ in range(int(n)):
            mujoco.mj_step(self.model, self.data)
            for hook in tuple(self._step_hooks):  # a hook may remove itself
                hook(self)

    def add_step_hook(self, hook: Callable[[SimWorld], None]) -> None:
        """Call `hook(world)` after every physics step (the suction gripper checks its load this way).

        While any hook is registered, `step(n)` runs the steps one by one from Python (slower).
        """
        self._step_hooks.append(hook)

    def remove_step_hook(self, hook: Callable[[SimWorld], None]) -> None:
        """Stop calling `hook` (no error when it is not registered)."""
        if hook in self._step_hooks:
            self._step_hooks.remove(hook)

    @property
    def T_world_base(self) -> np.ndarray:
        """(4, 4) pose of the arm's base in the world; the identity when the scene has no arm."""
        return np.eye(4) if self.robot is None else self.robot.T_world_base.copy()

    def forward(self) -> None:
        """Recompute derived quantities (poses, contacts) without advancing time."""
        mujoco.mj_forward(self.model, self.data)

    def is_finite(self) -> bool:
        """True when positions, velocities and accelerations are all finite."""
        d = self.data
        return bool(
            np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel)) and np.all(np.isfinite(d.qacc))
        )

    def settle(
        self,
        max_steps: int = 3000,
        lin_tol_m_s: float = 0.005,
        ang_tol_rad_s: float = 0.1,
        check_every: int = 50,
    ) -> int:
        """Step until every free object moves slower than `lin_tol_m_s` and turns slower than `ang_tol_rad_s`.

        Heaps of mesh hulls keep a slow rocking creep (a few mm/s) under MuJoCo's soft contacts; the
        tolerances accept that as rest. Returns the number of steps taken (max_steps when it never settled,
        logged as a warning). Raises InvalidInputError when the state becomes non-finite.
        """
        dofs = [
            self.model.jnt_dofadr[self.model.body_jntadr[o.body_id]]
            for o in self.objects
            if self.model.body_jntadr[o.body_id] >= 0
        ]
        if not dofs:
            return 0
        lin_idx = np.concatenate([np.arange(d, d + 3) for d in dofs])
        ang_idx = lin_idx + 3
        steps = 0
        while steps < max_steps:
            self.step(check_every)
            steps += check_every
            if not self.is_finite():
                raise InvalidInputError("the simulation diverged (non-finite state) while settling")
            qvel = self.data.qvel
            if np.max(np.abs(qvel[lin_idx])) < lin_tol_m_s and np.max(np.abs(qvel[ang_idx])) < ang_tol_rad_s:
                return steps
        log.warning(
            "scene did not settle within %d steps (max |qvel| %.3g)",
            max_steps,
            np.max(np.abs(self.data.qvel)),
        )
        return steps

    # --------------------------------------------------------------------------------------------------------
    # poses

    def object(self, name: str) -> ObjectInfo:
        try:
            return self._by_name[name]
        except KeyError:
            raise UnknownNameError("object", name, sorted(self._by_name)) from None

    def T_world_obj(self, name: str) -> np.ndarray:
        """(4, 4) pose of the object's canonical frame in the world [m], from the current data."""
        b = self.object(name).body_id
        return make_T(self.data.xmat[b].reshape(3, 3), self.data.xpos[b])

    def set_object_pose(self, name: str, T_world_obj: ArrayLike) -> None:
        """Teleport a free object (zero velocity) and recompute kinematics."""
        info = self.object(name)
        T = as_transform(T_world_obj, name="T_world_obj")
        jnt = self.model.body_jntadr[info.body_id]
        if jnt < 0:
            raise InvalidInputError(f"object {name!r} is fixed; it has no free joint to set")
        qadr, vadr = self.model.jnt_qposadr[jnt], self.model.jnt_dofadr[jnt]
        self.data.qpos[qadr : qadr + 3] = T[:3, 3]
        self.data.qpos[qadr + 3 : qadr + 7] = quat_wxyz_from_R(T[:3, :3])
        self.data.qvel[vadr : vadr + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _camera(self, name: str) -> CameraSpec:
        try:
            return self.cameras[name]
        except KeyError:
            raise UnknownNameError("camera", name, sorted(self.cameras)) from None

    def T_world_cam(self, camera: str) -> np.ndarray:
        """(4, 4) pose of the camera's OpenCV frame in the world [m] (mounted cameras follow their body)."""
        self._camera(camera)
        cid = self.model.camera(camera).id
        T_world_camgl = make_T(self.data.cam_xmat[cid].reshape(3, 3), self.data.cam_xpos[cid])
        return T_world_camgl @ T_CAMGL_CAM

    def set_camera_pose(self, camera: str, T_world_cam: ArrayLike) -> None:
        """Move a fixed camera (one on the world body) to `T_world_cam` (4, 4), OpenCV frame [m]."""
        spec = self._camera(camera)
        if spec.parent_body is not None:
            raise InvalidInputError(
                f"camera {camera!r} is mounted on {spec.parent_body!r}; move its body instead"
            )
        T_world_camgl = as_transform(T_world_cam, name="T_world_cam") @ T_CAMGL_CAM
        cid = self.model.camera(camera).id
        self.model.cam_pos[cid] = T_world_camgl[:3, 3]
        self.model.cam_quat[cid] = quat_wxyz_from_R(T_world_camgl[:3, :3])
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def set_mount_pose(self, body: str, T_world_body: ArrayLike) -> None:
        """Move a mocap mount body (see `SceneBuilder.add_mount_body`) and update camera poses."""
        bid = self.model.body(body).id
        mocap = self.model.body_mocapid[bid]
        if mocap < 0:
            raise InvalidInputError(f"body {body!r} is not a mocap mount")
        T = as_transform(T_world_body, name="T_world_body")
        self.data.mocap_pos[mocap] = T[:3, 3]
        self.data.mocap_quat[mocap] = quat_wxyz_from_R(T[:3, :3])
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def intrinsics(self, camera: str) -> CameraIntrinsics:
        return self._camera(camera).intrinsics

    # --------------------------------------------------------------------------------------------------------
    # rendering

    def _renderer(self, width: int, height: int) -> mujoco.Renderer:
        key = (width, height)
        if key not in self._renderers:
            self._renderers[key] = mujoco.Renderer(self.model, height=height, width=width)
        return self._renderers[key]

    def _far_m(self) -> float:
        return float(self.model.vis.map.zfar * self.model.stat.extent)

    def render_clean(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free colour (H, W, 3) uint8 and depth (H, W) float32 [m] (0 = nothing within range)."""
        spec = self._camera(camera)
        # Poses of the current qpos (mj_step leaves them one step behind): image and T_world_cam agree.
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        r = self._renderer(spec.width, spec.height)
        r.update_scene(self.data, camera=camera)
        color = r.render().copy()
        r.enable_depth_rendering()
        try:
            depth = r.render().copy()
        finally:
            r.disable_depth_rendering()
        depth[~np.isfinite(depth) | (depth >= _FAR_FRACTION * self._far_m())] = 0.0
        return color, depth.astype(np.float32)

    def render(
        self, camera: str, rng: np.random.Generator | None = None, noise: DepthNoiseConfig | None = None
    ) -> RGBDFrame:
        """One RGB-D frame with the camera's sensor model (or `noise`); `rng` is needed unless it is clean.

        Returns the library's `prompose_grasp.robot.RGBDFrame`: `rgb`, `depth_m`, `intrinsics`,
        `timestamp_s` (sim time) and `T_base_cam` in the arm's base frame (the world frame without an arm).
        The world pose of the camera is `T_world_cam(camera)`.
        """
        spec = self._camera(camera)
        model = noise or spec.noise
        color, depth = self.render_clean(camera)
        if model != DepthNoiseConfig(name=model.name):  # anything beyond the clean defaults draws noise
            if rng is None:
                raise InvalidInputError(
                    f"camera {camera!r} uses noise model {model.name!r}: pass a seeded rng"
                )
            depth = apply_depth_noise(depth, model, rng)
            color = apply_color_noise(color, model, rng)
        T_base_cam = self.T_world_cam(camera)
        if self.robot is not None:
            T_base_cam = self.robot.T_base_world @ T_base_cam
        return RGBDFrame(
            rgb=color,
            depth_m=depth,
            intrinsics=spec.intrinsics,
            timestamp_s=float(self.data.time),
            T_base_cam=T_base_cam,
        )

    def ground_truth_mask(self, camera: str) -> np.ndarray:
        """(H, W) int32 instance ids (segmentation render); 0 = no object. Ground truth: tests/data only."""
        spec = self._camera(camera)
        r = self._renderer(spec.width, spec.height)
        r.update_scene(self.data, camera=camera)
        r.enable_segmentation_rendering()
        try:
            seg = r.render()
        finally:
            r.disable_segmentation_rendering()
        ids, types = seg[..., 0], seg[..., 1]
        is_geom = (types == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids >= 0)
        return np.where(is_geom, self._geom_instance[np.where(is_geom, ids, -1)], 0).astype(np.int32)

    def ground_truth(self, camera: str) -> tuple[ObjectGroundTruth, ...]:
        """Amodal 9-DoF boxes of all objects in the camera's OpenCV frame. Ground truth: tests/data only."""
        T_cam_world = invert_T(self.T_world_cam(camera))
        out = []
        for o in self.objects:
            T_cam_obj = T_cam_world @ self.T_world_obj(o.name)
            out.append(
                ObjectGroundTruth(
                    o.name,
                    o.instance_id,
                    o.category,
                    o.prompt,
                    T_cam_obj[:3, :3],
                    T_cam_obj[:3, 3],
                    np.array(o.size, dtype=np.float64),
                    o.symmetry,
                    o.source,
                    dict(o.params),
                )
            )
        return tuple(out)

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
