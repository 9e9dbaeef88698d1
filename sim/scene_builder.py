"""The world builder: supports, objects, cameras and lights in one `mujoco.MjSpec`, compiled to `SimWorld`.

`SceneBuilder` owns the `MjSpec`; each `add_*` call adds named bodies and geoms to it and records what a
caller needs later (object canonical frames and sizes, support surfaces, camera specs). An arm and a gripper
can be attached into the same spec later (`builder.spec.attach(...)` or `add_mount_body` stand-ins that an
arm's body of the same name replaces). `build()` compiles once into a `SimWorld` holding model, data and
renderers.

Geom groups: 0 supports and floor (rendered, colliding), 2 object visuals (rendered, no contact), 3 object
collision hulls (contact only; group 3 is hidden by MuJoCo's default visualisation options).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import (
    as_transform,
    make_T,
    quat_wxyz_from_R,
)
from sim.appearance import BUILTIN_TEXTURES, Appearance
from sim.camera import T_CAMGL_CAM, CameraSpec
from sim.objects import ObjectAsset
from sim.world import ObjectInfo, SimWorld, Support

__all__ = ["EUR_PALLET_SIZE_M", "SceneBuilder"]

#: EUR pallet (EPAL 1): 1200 x 800 x 144 mm.
EUR_PALLET_SIZE_M = (1.2, 0.8, 0.144)

_GROUP_SUPPORT, _GROUP_OBJECT_VISUAL, _GROUP_OBJECT_COLLISION = 0, 2, 3


@dataclass
class _PendingObject:
    info: ObjectInfo
    body_name: str
    visual_geom_names: list[str] = field(default_factory=list)


def _cylindrical_uv(vertices: np.ndarray) -> np.ndarray:
    """(N, 2) texture coordinates wrapping a texture around the canonical y axis (u: angle, v: height)."""
    u = (np.arctan2(vertices[:, 2], vertices[:, 0]) + math.pi) / (2.0 * math.pi)
    span = np.ptp(vertices[:, 1]) or 1.0
    v = (vertices[:, 1] - vertices[:, 1].min()) / span
    return np.stack([u, v], axis=1)


class SceneBuilder:
    """Builds a scene into one `mujoco.MjSpec`.

    >>> b = SceneBuilder("demo")
    >>> table = b.add_table()
    >>> b.add_object(make_object("mug"), "mug", upright_pose(make_object("mug"), table))  # doctest: +SKIP
    >>> world = b.build()  # doctest: +SKIP
    """

    def __init__(
        self,
        name: str = "scene",
        timestep_s: float = 0.002,
        max_image_size: tuple[int, int] = (1280, 960),
        msaa_samples: int = 0,
        shadow_size: int = 1024,
    ):
        if not (math.isfinite(timestep_s) and 0.0 < timestep_s <= 0.05):
            raise InvalidInputError(f"timestep_s must lie in (0, 0.05] s, got {timestep_s}")
        self.spec = mujoco.MjSpec()
        self.spec.modelname = name
        self.spec.option.timestep = timestep_s
        # Elliptic friction cones with a high impedance ratio: MuJoCo's advice for grasping and stacking
        # (less slip and creep than pyramidal cones).
        self.spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        self.spec.option.impratio = 10.0
        self.spec.visual.global_.offwidth = int(max_image_size[0])
        self.spec.visual.global_.offheight = int(max_image_size[1])
        # Near plane relative to the model extent: a wrist camera sees objects from a few centimetres.
        self.spec.visual.map.znear = 0.002
        self.spec.visual.map.zfar = 20.0
        # Multisampling and shadow-map size dominate software (llvmpipe) rendering time. The defaults are a
        # depth camera's look (no anti-aliasing, as a RealSense colour image) and the dataset generator's:
        # a 640x480 colour frame of the tabletop takes ~170 ms on 2 CPU cores, against ~430 ms with 4x MSAA
        # and 2048 px shadow maps (measured under load ~4, seed 300).
        self.spec.visual.quality.offsamples = int(msaa_samples)
        self.spec.visual.quality.shadowsize = int(shadow_size)
        self.spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
        self.spec.visual.headlight.diffuse = [0.35, 0.35, 0.35]
        self.spec.visual.headlight.specular = [0.1, 0.1, 0.1]
        self._objects: list[_PendingObject] = []
        self._supports: dict[str, Support] = {}
        self._place_targets: dict[str, Support] = {}
        self._cameras: dict[str, CameraSpec] = {}
        self._names: set[str] = set()
        self._n_assets = 0
        self._robot = None  # set by sim.robot_scene.add_robot

    # --------------------------------------------------------------------------------------------------------
    # helpers

    def _unique(self, name: str) -> str:
        if not name:
            raise InvalidInputError("names must be non-empty")
        if name in self._names:
            raise InvalidInputError(f"the name {name!r} is already used in this scene")
        self._names.add(name)
        return name

    def _asset_name(self, stem: str) -> str:
        self._n_assets += 1
        return f"{stem}_{self._n_assets}"

    def _material(self, appearance: Appearance, stem: str) -> str:
        mat = self.spec.add_material()
        mat.name = self._asset_name(f"mat_{stem}")
        mat.rgba = list(appearance.rgba)
        mat.specular = appearance.specular
        mat.shininess = appearance.shininess
        mat.reflectance = appearance.reflectance
        if appearance.texture is not None:
            tex = self.spec.add_texture()
            tex.name = self._asset_name(f"tex_{stem}")
            tex.type = mujoco.mjtTexture.mjTEXTURE_2D
            if appearance.texture in BUILTIN_TEXTURES:
                tex.builtin = {
                    "checker": mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                    "gradient": mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                    "flat": mujoco.mjtBuiltin.mjBUILTIN_FLAT,
                    "noise": mujoco.mjtBuiltin.mjBUILTIN_FLAT,
                }[appearance.texture]
                tex.rgb1 = list(appearance.rgba[:3])
                tex.rgb2 = list(appearance.rgb2)
                tex.width = tex.height = 256
                if appearance.texture == "noise":  # speckle: MuJoCo sprinkles random pixels of markrgb
                    tex.mark = mujoco.mjtMark.mjMARK_RANDOM
                    tex.random = 0.15
                    tex.markrgb = list(appearance.rgb2)
                mat.rgba = [1.0, 1.0, 1.0, appearance.rgba[3]]
            else:
                tex.file = str(Path(appearance.texture).resolve())
            textures = [""] * int(mujoco.mjtTextureRole.mjNTEXROLE)
            textures[int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] = tex.name
            mat.textures = textures
            mat.texrepeat = list(appearance.texrepeat)
            mat.texuniform = True
        return mat.name

    def _static_box(
        self, body, name: str, half_extents: Sequence[float], pos: Sequence[float], material: str
    ) -> None:
        g = body.add_geom()
        g.name = name
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = list(half_extents)
        g.pos = list(pos)
        g.material = material
        g.group = _GROUP_SUPPORT

    def _support_body(self, name: str, T_world_base: ArrayLike):
        T = as_transform(T_world_base, name="T_world_base")
        body = self.spec.worldbody.add_body()
        body.name = name
        body.pos = T[:3, 3].tolist()
        body.quat = quat_wxyz_from_R(T[:3, :3]).tolist()
        return body, T

    def _register_support(self, support: Support) -> Support:
        self._supports[support.name] = support
        return support

    # --------------------------------------------------------------------------------------------------------
    # environment

    def add_floor(
        self, size_m: tuple[float, float] = (6.0, 6.0), appearance: Appearance | None = None
    ) -> Support:
        """A floor plane at z = 0 (a support of kind "floor")."""
        name = self._unique("floor")
        app = appearance or Appearance(
            rgba=(0.55, 0.55, 0.52, 1.0), texture="checker", rgb2=(0.45, 0.45, 0.43)
        )
        g = self.spec.worldbody.add_geom()
        g.name = name
        g.type = mujoco.mjtGeom.mjGEOM_PLANE
        g.size = [size_m[0] / 2.0, size_m[1] / 2.0, 0.05]
        g.material = self._material(app, "floor")
        g.group = _GROUP_SUPPORT
        half = np.array(size_m, dtype=np.float64) / 2.0
        return self._register_support(Support(name, "floor", np.eye(4), half))

    def add_skybox(
        self, top_rgb: Sequence[float] = (0.62, 0.7, 0.8), bottom_rgb: Sequence[float] = (0.12, 0.12, 0.15)
    ) -> None:
        """A gradient sky behind everything (colour only: depth there reads as no return)."""
        tex = self.spec.add_texture()
        tex.name = self._asset_name("skybox")
        tex.type = mujoco.mjtTexture.mjTEXTURE_SKYBOX
        tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_GRADIENT
        tex.rgb1 = list(top_rgb)
        tex.rgb2 = list(bottom_rgb)
        tex.width = tex.height = 256

    def add_light(
        self,
        pos_m: ArrayLike,
        direction: ArrayLike = (0.0, 0.0, -1.0),
        diffuse: float | Sequence[float] = 0.6,
        specular: float = 0.2,
        castshadow: bool = True,
        name: str | None = None,
    ) -> str:
        """A spot light at `pos_m` (3,) [m] pointing along `direction` (3,)."""
        light = self.spec.worldbody.add_light()
        light.name = self._unique(name or self._asset_name("light"))
        light.pos = np.asarray(pos_m, dtype=np.float64).tolist()
        d = np.asarray(direction, dtype=np.float64)
        light.dir = (d / np.linalg.norm(d)).tolist()
        light.diffuse = list(np.broadcast_to(np.asarray(diffuse, dtype=np.float64), (3,)))
        light.specular = [specular] * 3
        light.castshadow = bool(castshadow)
        return light.name

    def set_headlight(self, ambient: float, diffuse: float, specular: float = 0.1) -> None:
        """The camera-attached headlight (fills shadows); intensities in [0, 1]."""
        self.spec.visual.headlight.ambient = [ambient] * 3
        self.spec.visual.headlight.diffuse = [diffuse] * 3
        self.spec.visual.headlight.specular = [specular] * 3

    # --------------------------------------------------------------------------------------------------------
    # supports

    def add_table(
        self,
        name: str = "table",
        size_xy_m: tuple[float, float] = (1.2, 0.8),
        height_m: float = 0.75,
        T_world_base: ArrayLike | None = None,
        top_thickness_m: float = 0.04,
        appearance: Appearance | None = None,
    ) -> Support:
        """A table: a top slab and four legs. `T_world_base` is the footprint centre on the floor, z up."""
        name = self._unique(name)
        if min(size_xy_m) <= 0 or height_m <= top_thickness_m or top_thickness_m <= 0:
            raise InvalidInputError(
                f"table needs positive size and height > top thickness, got {size_xy_m}, {height_m}"
            )
        body, T = self._support_body(name, np.eye(4) if T_world_base is None else T_world_base)
        app = appearance or Appearance(
            rgba=(0.62, 0.45, 0.3, 1.0), texture="gradient", rgb2=(0.5, 0.35, 0.22)
        )
        mat = self._material(app, name)
        hx, hy = size_xy_m[0] / 2.0, size_xy_m[1] / 2.0
        self._static_box(
            body,
            f"{name}_top",
            [hx, hy, top_thickness_m / 2.0],
            [0, 0, height_m - top_thickness_m / 2.0],
            mat,
        )
        leg = 0.03
        leg_mat = self._material(Appearance(rgba=(0.25, 0.25, 0.27, 1.0), specular=0.5), f"{name}_legs")
        leg_h = (height_m - top_thickness_m) / 2.0
        for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            self._static_box(
                body,
                f"{name}_leg{i}",
                [leg, leg, leg_h],
                [sx * (hx - 2 * leg), sy * (hy - 2 * leg), leg_h],
                leg_mat,
            )
        T_surface = T @ make_T(np.eye(3), [0.0, 0.0, height_m])
        return self._register_support(Support(name, "table", T_surface, np.array([hx, hy])))

    def add_bin(
        self,
        name: str = "bin",
        inner_size_xy_m: tuple[float, float] = (0.4, 0.3),
        wall_height_m: float = 0.15,
        wall_thickness_m: float = 0.01,
        T_world_base: ArrayLike | None = None,
        appearance: Appearance | None = None,
    ) -> Support:
        """An open box (tote). `T_world_base`: centre of its underside; the surface is the inner floor."""
        name = self._unique(name)
        if min(inner_size_xy_m) <= 0 or wall_height_m <= 0 or wall_thickness_m <= 0:
            raise InvalidInputError("bin sizes must be positive")
        body, T = self._support_body(name, np.eye(4) if T_world_base is None else T_world_base)
        mat = self._material(appearance or Appearance(rgba=(0.15, 0.35, 0.65, 1.0), specular=0.4), name)
        ix, iy, t, h = inner_size_xy_m[0] / 2.0, inner_size_xy_m[1] / 2.0, wall_thickness_m, wall_height_m
        self._static_box(body, f"{name}_floor", [ix + t, iy + t, t / 2.0], [0, 0, t / 2.0], mat)
        zc = t + h / 2.0
        self._static_box(body, f"{name}_wall_px", [t / 2.0, iy + t, h / 2.0], [ix + t / 2.0, 0, zc], mat)
        self._static_box(body, f"{name}_wall_nx", [t / 2.0, iy + t, h / 2.0], [-ix - t / 2.0, 0, zc], mat)
        self._static_box(body, f"{name}_wall_py", [ix, t / 2.0, h / 2.0], [0, iy + t / 2.0, zc], mat)
        self._static_box(body, f"{name}_wall_ny", [ix, t / 2.0, h / 2.0], [0, -iy - t / 2.0, zc], mat)
        T_surface = T @ make_T(np.eye(3), [0.0, 0.0, t])
        return self._register_support(Support(name, "bin", T_surface, np.array([ix, iy]), wall_height_m))

    def add_conveyor(
        self,
        name: str = "conveyor",
        length_m: float = 2.0,
        width_m: float = 0.5,
        height_m: float = 0.8,
        T_world_base: ArrayLike | None = None,
        appearance: Appearance | None = None,
    ) -> Support:
        """A belt conveyor along its x axis: frame, belt, side guides, legs. The surface is the belt top."""
        name = self._unique(name)
        if length_m <= 0 or width_m <= 0 or height_m <= 0.1:
            raise InvalidInputError("conveyor length and width must be > 0 and height > 0.1 m")
        body, T = self._support_body(name, np.eye(4) if T_world_base is None else T_world_base)
        belt = self._material(
            appearance or Appearance(rgba=(0.12, 0.12, 0.12, 1.0), texture="noise", rgb2=(0.2, 0.2, 0.2)),
            name,
        )
        frame = self._material(
            Appearance(rgba=(0.6, 0.62, 0.65, 1.0), specular=0.7, shininess=0.6), f"{name}_frame"
        )
        hl, hw = length_m / 2.0, width_m / 2.0
        belt_t, frame_h = 0.01, 0.08
        self._static_box(
            body,
            f"{name}_frame",
            [hl, hw + 0.02, frame_h / 2.0],
            [0, 0, height_m - belt_t - frame_h / 2.0],
            frame,
        )
        self._static_box(body, f"{name}_belt", [hl, hw, belt_t / 2.0], [0, 0, height_m - belt_t / 2.0], belt)
        for side in (1, -1):  # low side guides
            self._static_box(
                body,
                f"{name}_guide{side:+d}",
                [hl, 0.01, 0.02],
                [0, side * (hw + 0.01), height_m + 0.01],
                frame,
            )
        leg_h = (height_m - belt_t - frame_h) / 2.0
        for i, x in enumerate(np.linspace(-hl + 0.05, hl - 0.05, max(2, int(length_m / 1.0) + 1))):
            for side in (1, -1):
                self._static_box(
                    body,
                    f"{name}_leg{i}{'ab'[side > 0]}",
                    [0.025, 0.025, leg_h],
                    [x, side * hw, leg_h],
                    frame,
                )
        T_surface = T @ make_T(np.eye(3), [0.0, 0.0, height_m])
        return self._register_support(Support(name, "conveyor", T_surface, np.array([hl, hw])))

    def add_pallet(
        self,
        name: str = "pallet",
        T_world_base: ArrayLike | None = None,
        appearance: Appearance | None = None,
    ) -> Support:
        """A EUR pallet (EPAL 1, 1200 x 800 x 144 mm) with its deck boards, cross boards, blocks and runners.

        x runs along the 1200 mm side. From the floor up: 3 bottom boards (22 mm, along x: 100/145/100 mm
        wide), 9 blocks (78 mm; 145 mm along x; 100 mm wide in the outer rows, 145 mm in the middle row),
        3 cross boards (22 mm, along y, 145 mm wide) and 5 top deck boards (22 mm, along x:
        145/100/100/100/145 mm wide, equal gaps). The surface is the top of the deck at 144 mm.
        """
        name = self._unique(name)
        body, T = self._support_body(name, np.eye(4) if T_world_base is None else T_world_base)
        wood = self._material(
            appearance or Appearance(rgba=(0.78, 0.64, 0.45, 1.0), texture="noise", rgb2=(0.65, 0.5, 0.33)),
            name,
        )
        L, W, H = EUR_PALLET_SIZE_M
        board, block_h = 0.022, 0.078
        row_y = (-(W / 2.0 - 0.05), 0.0, W / 2.0 - 0.05)  # block rows / bottom boards
        row_w = (0.100, 0.145, 0.100)
        col_x = (-(L / 2.0 - 0.0725), 0.0, L / 2.0 - 0.0725)  # block columns / cross boards
        for i, (y, w) in enumerate(zip(row_y, row_w)):
            self._static_box(
                body, f"{name}_bottom{i}", [L / 2.0, w / 2.0, board / 2.0], [0, y, board / 2.0], wood
            )
            for j, x in enumerate(col_x):
                self._static_box(
                    body,
                    f"{name}_block{i}{j}",
                    [0.0725, w / 2.0, block_h / 2.0],
                    [x, y, board + block_h / 2.0],
                    wood,
                )
        z_cross = board + block_h + board / 2.0
        for j, x in enumerate(col_x):
            self._static_box(body, f"{name}_cross{j}", [0.0725, W / 2.0, board / 2.0], [x, 0, z_cross], wood)
        deck_w = (0.145, 0.100, 0.100, 0.100, 0.145)
        gap = (W - sum(deck_w)) / 4.0
        y = -W / 2.0
        for k, w in enumerate(deck_w):
            self._static_box(
                body,
                f"{name}_deck{k}",
                [L / 2.0, w / 2.0, board / 2.0],
                [0, y + w / 2.0, H - board / 2.0],
                wood,
            )
            y += w + gap
        T_surface = T @ make_T(np.eye(3), [0.0, 0.0, H])
        return self._register_support(Support(name, "pallet", T_surface, np.array([L / 2.0, W / 2.0])))

    def add_place_target(self, name: str, support: Support) -> None:
        """Mark a support (its top surface) as a place target under `name`."""
        if support.name not in self._supports:
            raise UnknownNameError("support", support.name, sorted(self._supports))
        self._place_targets[name] = support

    # --------------------------------------------------------------------------------------------------------
    # objects, mounts, cameras

    def add_object(
        self,
        asset: ObjectAsset,
        name: str,
        T_world_obj: ArrayLike,
        prompt: str | None = None,
        appearance: Appearance | None = None,
        fixed: bool = False,
        density_kg_m3: float = 300.0,
        friction: float = 0.8,
    ) -> ObjectInfo:
        """Add an object whose canonical frame sits at `T_world_obj` (4, 4) [m]; free-floating unless `fixed`.

        Returns the object's metadata (its instance id is its 1-based order of addition).
        """
        name = self._unique(name)
        T = as_transform(T_world_obj, name="T_world_obj")
        if not (math.isfinite(density_kg_m3) and density_kg_m3 > 0):
            raise InvalidInputError(f"density_kg_m3 must be > 0, got {density_kg_m3}")
        body = self.spec.worldbody.add_body()
        body.name = f"obj_{name}"
        body.pos = T[:3, 3].tolist()
        body.quat = quat_wxyz_from_R(T[:3, :3]).tolist()
        if not fixed:
            joint = body.add_freejoint()
            joint.name = f"obj_{name}_free"
        app = appearance or Appearance()
        mat = self._material(app, name)
        pending = _PendingObject(
            ObjectInfo(
                name=name,
                instance_id=len(self._objects) + 1,
                category=asset.category,
                prompt=prompt or asset.category,
                size=asset.size,
                symmetry=asset.symmetry,
                source=asset.source,
                params=dict(asset.params),
            ),
            body.name,
        )
        for i, part in enumerate(asset.parts):
            mesh = self.spec.add_mesh()
            mesh.name = self._asset_name(f"mesh_{name}_vis{i}")
            mesh.uservert = np.asarray(part.vertices, dtype=np.float32).ravel()
            mesh.userface = np.asarray(part.faces, dtype=np.int32).ravel()
            if app.texture is not None:
                mesh.usertexcoord = _cylindrical_uv(np.asarray(part.vertices)).astype(np.float32).ravel()
            mesh.inertia = (
                mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
            )  # files may be open; no mass from visuals
            g = body.add_geom()
            g.name = f"obj_{name}_vis{i}"
            g.type = mujoco.mjtGeom.mjGEOM_MESH
            g.meshname = mesh.name
            g.material = mat
            g.group = _GROUP_OBJECT_VISUAL
            g.contype = 0
            g.conaffinity = 0
            g.density = 0.0
            pending.visual_geom_names.append(g.name)
        for i, hull in enumerate(asset.collision):
            mesh = self.spec.add_mesh()
            mesh.name = self._asset_name(f"mesh_{name}_col{i}")
            mesh.uservert = np.asarray(hull.vertices, dtype=np.float32).ravel()
            mesh.userface = np.asarray(hull.faces, dtype=np.int32).ravel()
            g = body.add_geom()
            g.name = f"obj_{name}_col{i}"
            g.type = mujoco.mjtGeom.mjGEOM_MESH
            g.meshname = mesh.name
            g.group = _GROUP_OBJECT_COLLISION
            g.rgba = [0.5, 0.5, 0.5, 0.0]
            g.density = density_kg_m3
            g.friction = [friction, 0.01, 0.001]
            g.condim = 4
        self._objects.append(pending)
        return pending.info

    def add_mount_body(self, name: str, T_world_body: ArrayLike) -> str:
        """A mocap body (moved by setting `data.mocap_pos/quat`) to carry a camera before an arm exists.

        A wrist camera mounted on "flange" now keeps its name when the arm's flange body replaces this one.
        """
        name = self._unique(name)
        T = as_transform(T_world_body, name="T_world_body")
        body = self.spec.worldbody.add_body()
        body.name = name
        body.mocap = True
        body.pos = T[:3, 3].tolist()
        body.quat = quat_wxyz_from_R(T[:3, :3]).tolist()
        return name

    def add_camera(self, camera: CameraSpec) -> CameraSpec:
        """Add a fixed (parent_body None) or mounted camera; its pose is the OpenCV frame in the parent."""
        self._unique(f"camera:{camera.name}")
        if camera.parent_body is None:
            parent = self.spec.worldbody
        else:
            parent = self.spec.body(camera.parent_body)
            if parent is None:
                known = sorted(b.name for b in self.spec.bodies if b.name)
                raise UnknownNameError("camera parent body", camera.parent_body, known)
        T_parent_camgl = camera.T_parent_cam @ T_CAMGL_CAM
        cam = parent.add_camera()
        cam.name = camera.name
        cam.pos = T_parent_camgl[:3, 3].tolist()
        cam.quat = quat_wxyz_from_R(T_parent_camgl[:3, :3]).tolist()
        cam.fovy = float(camera.fovy_deg)
        cam.resolution = [camera.width, camera.height]
        self._cameras[camera.name] = camera
        g = self.spec.visual.global_
        g.offwidth = max(g.offwidth, camera.width)
        g.offheight = max(g.offheight, camera.height)
        return camera

    @property
    def supports(self) -> dict[str, Support]:
        return dict(self._supports)

    @property
    def objects(self) -> tuple[ObjectInfo, ...]:
        return tuple(p.info for p in self._objects)

    def build(self) -> SimWorld:
        """Compile the spec into a `SimWorld` (model, data, renderers)."""
        if self._robot is not None:
            self._robot.before_compile(self)
        try:
            model = self.spec.compile()
        except Exception as exc:  # MuJoCo raises ValueError with the compiler's message
            raise InvalidInputError(
                f"MuJoCo could not compile the scene {self.spec.modelname!r}: {exc}"
            ) from exc
        objects = []
        for p in self._objects:
            body_id = model.body(p.body_name).id
            geom_ids = tuple(model.geom(n).id for n in p.visual_geom_names)
            info = p.info
            objects.append(
                ObjectInfo(
                    info.name,
                    info.instance_id,
                    info.category,
                    info.prompt,
                    info.size,
                    info.symmetry,
                    info.source,
                    info.params,
                    body_id,
                    geom_ids,
                )
            )
        robot = None if self._robot is None else self._robot.resolve(model)
        return SimWorld(
            model, objects, dict(self._cameras), dict(self._supports), dict(self._place_targets), robot
        )
