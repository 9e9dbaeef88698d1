"""The world builder: supports, objects, cameras and lights in one `mujoco.MjSpec`, compiled to `SimWorld`.

`SceneBuilder` owns the `MjSpec`; each `add_*` call adds named bodies and geoms to it and records what a
caller needs later (object canonical frames and sizes, support surfaces, camera specs). An arm and a gripper
can be attached into the same spec later (`builder.spec.attach(...)` or `add_mount_body` stand-ins that an
arm's body of the same name replaces). `build()` compiles once into a `SimWorld` holding model, data and
renderers.

Frames: `world` is MuJoCo's world (z up, metres). A support's `T_world_surface` has its origin at the centre
of the top surface, z up. An object body frame is the object's canonical frame (origin at the amodal box
centre, +y the object's up), so `T_world_obj` is the body pose and ground truth needs no offsets. Cameras use
OpenCV frames (`sim.camera`).

Geom groups: 0 supports and floor (rendered, colliding), 2 object visuals (rendered, no contact), 3 object
collision hulls (contact only; group 3 is hidden by MuJoCo's default visualisation options).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

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
from sim.objects import ObjectAsset

__all__ = [
    "BUILTIN_TEXTURES",
    "EUR_PALLET_SIZE_M",
    "Appearance",
    "ObjectGroundTruth",
    "ObjectInfo",
    "SceneBuilder",
    "SimWorld",
    "Support",
    "random_appearance",
]

log = logging.getLogger(__name__)

#: EUR pallet (EPAL 1): 1200 x 800 x 144 mm.
EUR_PALLET_SIZE_M = (1.2, 0.8, 0.144)

#: Procedural textures MuJoCo generates itself (no image file needed).
BUILTIN_TEXTURES = ("checker", "gradient", "flat", "noise")

_GROUP_SUPPORT, _GROUP_OBJECT_VISUAL, _GROUP_OBJECT_COLLISION = 0, 2, 3

#: Depth readings at or beyond this fraction of the far clipping plane are background, not geometry.
_FAR_FRACTION = 0.999


@dataclass(frozen=True)
class Appearance:
    """Surface look. `texture` is None, one of `BUILTIN_TEXTURES`, or a PNG file path.

    Attributes:
        rgba: base colour (4,) in [0, 1]; with a texture, it tints it.
        rgb2: second colour of builtin textures (3,) in [0, 1].
        specular, shininess, reflectance: MuJoCo material terms in [0, 1].
        texrepeat: texture repetitions per metre (builtin) or per surface.
    """

    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    texture: str | None = None
    rgb2: tuple[float, float, float] = (0.3, 0.3, 0.3)
    specular: float = 0.3
    shininess: float = 0.3
    reflectance: float = 0.0
    texrepeat: tuple[float, float] = (4.0, 4.0)

    def __post_init__(self) -> None:
        rgba = np.asarray(self.rgba, dtype=np.float64)
        if rgba.shape != (4,) or not np.all((rgba >= 0) & (rgba <= 1)):
            raise InvalidInputError(f"rgba must be 4 numbers in [0, 1], got {self.rgba!r}")
        for key in ("specular", "shininess", "reflectance"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise InvalidInputError(f"Appearance.{key} must lie in [0, 1], got {getattr(self, key)}")
        if self.texture is not None and self.texture not in BUILTIN_TEXTURES:
            if not Path(self.texture).is_file():
                raise InvalidInputError(
                    f"texture {self.texture!r} is neither a builtin ({', '.join(BUILTIN_TEXTURES)}) "
                    "nor an image file"
                )


def random_appearance(rng: np.random.Generator, kind: str = "object") -> Appearance:
    """A randomised appearance for data generation.

    kind "object": saturated or muted colours, plastic to metal-like shine, sometimes a texture. kind "table":
    wood-, stone- or cloth-like builtin textures in plausible colours.
    """
    if kind not in ("object", "table"):
        raise UnknownNameError("appearance kind", kind, ("object", "table"))
    hsv = rng.uniform([0.0, 0.1, 0.25], [1.0, 0.9, 0.95])
    rgb = _hsv_to_rgb(*hsv)
    if kind == "object":
        texture = rng.choice(["none", "none", "none", "checker", "noise"])
        return Appearance(
            rgba=(*rgb, 1.0),
            texture=None if texture == "none" else str(texture),
            rgb2=tuple(np.clip(np.asarray(rgb) * rng.uniform(0.4, 0.9), 0, 1)),
            specular=float(rng.uniform(0.0, 0.8)),
            shininess=float(rng.uniform(0.0, 0.8)),
            texrepeat=(float(rng.uniform(2, 8)), float(rng.uniform(2, 8))),
        )
    base = np.array(_hsv_to_rgb(rng.uniform(0.02, 0.15), rng.uniform(0.1, 0.6), rng.uniform(0.3, 0.9)))
    if rng.random() < 0.3:  # grey/white/black tables exist too
        base = np.full(3, rng.uniform(0.15, 0.95))
    return Appearance(
        rgba=(*base, 1.0),
        texture=str(rng.choice(["checker", "gradient", "noise", "flat"])),
        rgb2=tuple(np.clip(base * rng.uniform(0.6, 1.0), 0, 1)),
        specular=float(rng.uniform(0.0, 0.4)),
        shininess=float(rng.uniform(0.0, 0.5)),
        reflectance=float(rng.uniform(0.0, 0.1)),
        texrepeat=(float(rng.uniform(1, 12)), float(rng.uniform(1, 12))),
    )


def _hsv_to_rgb(h: float, s: float, v: float) -> tuple[float, float, float]:
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]


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


# ------------------------------------------------------------------------------------------------------------
# placement


def upright_pose(
    asset: ObjectAsset,
    support: Support,
    xy_m: ArrayLike = (0.0, 0.0),
    yaw_rad: float = 0.0,
    clearance_m: float = 0.0,
) -> np.ndarray:
    """T_world_obj (4, 4) standing the object upright (canonical +y along the surface's z) on a support.

    `xy_m` (2,) is the position on the surface in the surface frame [m]; `yaw_rad` turns about the surface z;
    `clearance_m` lifts the box bottom above the surface.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise InvalidInputError(f"xy_m must be (2,) finite, got {xy_m!r}")
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    R_yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    R_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # obj +y -> surface +z
    t = np.array([xy[0], xy[1], asset.size[1] / 2.0 + clearance_m])
    return support.T_world_surface @ make_T(R_yaw @ R_up, t)


def footprint_radius_m(asset: ObjectAsset) -> float:
    """Radius [m] of the disc covering the object's upright footprint (its x-z extents) at any yaw."""
    return 0.5 * math.hypot(asset.size[0], asset.size[2])


def sample_upright_placements(
    assets: Sequence[ObjectAsset],
    support: Support,
    rng: np.random.Generator,
    margin_m: float = 0.01,
    region_half_extents_m: ArrayLike | None = None,
    region_centre_m: ArrayLike = (0.0, 0.0),
    max_tries: int = 500,
    clearance_m: float = 0.0,
) -> list[np.ndarray]:
    """Non-overlapping upright poses with random yaw for `assets` on a support (footprint discs + margin).

    Raises InvalidInputError when they cannot all be fitted in `max_tries` draws per object.
    """
    half = np.asarray(
        support.half_extents_xy_m if region_half_extents_m is None else region_half_extents_m, float
    )
    centre = np.asarray(region_centre_m, dtype=np.float64)
    placed: list[tuple[np.ndarray, float]] = []
    poses: list[np.ndarray] = [np.eye(4)] * len(assets)
    # Largest first: small objects fill the gaps the big ones leave (random sequential packing).
    order = sorted(range(len(assets)), key=lambda i: -footprint_radius_m(assets[i]))
    for k in order:
        asset = assets[k]
        r = footprint_radius_m(asset)
        lim = half - r - margin_m
        if np.any(lim < 0):
            raise InvalidInputError(
                f"object {k} ({asset.category}, footprint radius {r:.3f} m) does not fit the region"
            )
        for _ in range(max_tries):
            xy = centre + rng.uniform(-lim, lim)
            if all(np.linalg.norm(xy - p) >= r + rp + margin_m for p, rp in placed):
                break
        else:
            raise InvalidInputError(
                f"could not place object {k} ({asset.category}) without overlap on {support.name!r}"
            )
        placed.append((xy, r))
        poses[k] = upright_pose(asset, support, xy, float(rng.uniform(-math.pi, math.pi)), clearance_m)
    return poses
