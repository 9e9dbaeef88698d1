"""Values of the grasp layer: inputs (objects, support plane), configuration, and results (grasps, plans).

All poses and points are in the robot's `base` frame [m]. Convert the estimator's camera-frame outputs with
one call each: `pose_cam.transformed(T_base_cam)`, `mesh_cam.copy().apply_transform(T_base_cam)`,
`Plane.from_camera(plane.normal_cam, plane.offset_m, T_base_cam)`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import as_transform

__all__ = ["Grasp", "GraspConfig", "GraspPlan", "ObjectModel", "Plane"]


def _readonly(a: ArrayLike) -> np.ndarray:
    out = np.array(a, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Plane:
    """A plane in `base`: points x with n . x + offset_m = 0; x's signed height above it is n . x + offset_m.

    Same convention as the estimator's `SupportPlane` (there in the camera frame).

    Attributes:
        normal: (3,) float64 unit normal, pointing up (the side objects stand on).
        offset_m: the plane offset d [m].
    """

    normal: np.ndarray
    offset_m: float

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=np.float64)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
            raise InvalidInputError(f"Plane.normal must be a finite non-zero (3,) vector, got {n!r}")
        if not math.isfinite(float(self.offset_m)):
            raise InvalidInputError(f"Plane.offset_m must be finite [m], got {self.offset_m!r}")
        norm = float(np.linalg.norm(n))
        object.__setattr__(self, "normal", _readonly(n / norm))
        object.__setattr__(self, "offset_m", float(self.offset_m) / norm)

    @classmethod
    def horizontal(cls, z_m: float) -> Plane:
        """The plane z = z_m in `base`, normal +z."""
        return cls(np.array([0.0, 0.0, 1.0]), -float(z_m))

    @classmethod
    def from_camera(cls, normal_cam: ArrayLike, offset_m: float, T_base_cam: ArrayLike) -> Plane:
        """The estimator's camera-frame plane (n_cam . x_cam + d = 0) expressed in `base`."""
        T = as_transform(T_base_cam, "T_base_cam")
        n = T[:3, :3] @ np.asarray(normal_cam, dtype=np.float64)
        return cls(n, float(offset_m) - float(n @ T[:3, 3]))

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed heights (...,) [m] of points (..., 3) above the plane."""
        return points @ self.normal + self.offset_m

    def point(self) -> np.ndarray:
        """(3,) the point of the plane nearest the base origin [m]."""
        return -self.offset_m * self.normal


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """An object as the grasp layer sees it: its estimated 9-DoF box in `base`, optionally its scaled mesh.

    Attributes:
        name: a label used in rejection reasons and obstacle names.
        pose: `Pose9D` in `base` (R_base_obj, box centre, full extents [m]); object +y is its up.
        mesh: the scaled prior mesh in `base` [m] (a `trimesh.Trimesh`), or None (the box is used).
        family: shape family of the prior ("mug", "bowl", "bottle", "carton", ...); "" when unknown.
        symmetry: the prior's symmetry name ("none", "y_axis", ...).
        mass_kg: mass when known (suction payload check), else None.
        kind: "object" (a thing on the support) or "fixture" (bin walls, conveyor frame, ...): rejection
            reasons are `collision_<kind>`.
        surface_points: (N, 3) the object's seen surface in `base` [m] (`Estimate.surface_cam`), or None:
            with a support plane, the jaws may close across a narrow part of it (`surface.section_grasps`).
    """

    name: str
    pose: Pose9D
    mesh: Any = None
    family: str = ""
    symmetry: str = "none"
    mass_kg: float | None = None
    kind: str = "object"
    surface_points: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.pose, Pose9D):
            got = type(self.pose).__name__
            raise InvalidInputError(f"ObjectModel.pose must be a Pose9D in base, got {got}")
        if self.mesh is not None:
            v = np.asarray(getattr(self.mesh, "vertices", None), dtype=np.float64)
            f = np.asarray(getattr(self.mesh, "faces", None))
            if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)) or f.ndim != 2 or f.shape[1] != 3:
                raise InvalidInputError(
                    "ObjectModel.mesh must be a triangle mesh: finite (V, 3) vertices [m] and (F, 3) faces"
                )
        mass = self.mass_kg
        number = not isinstance(mass, bool) and isinstance(mass, int | float)
        if mass is not None and not (number and math.isfinite(mass) and mass > 0):
            raise InvalidInputError(f"ObjectModel.mass_kg must be finite and > 0 kg, got {self.mass_kg!r}")
        if self.kind not in ("object", "fixture"):
            raise InvalidInputError(f"ObjectModel.kind must be 'object' or 'fixture', got {self.kind!r}")
        if self.surface_points is not None:
            pts = np.asarray(self.surface_points)
            if pts.ndim != 2 or pts.shape[1] != 3 or not np.issubdtype(pts.dtype, np.floating):
                got = f"{pts.dtype} {pts.shape}"
                raise InvalidInputError(f"ObjectModel.surface_points must be (N, 3) floats [m], got {got}")
            if not np.all(np.isfinite(pts)):
                raise InvalidInputError("ObjectModel.surface_points must be finite")
            object.__setattr__(self, "surface_points", _readonly(pts.astype(np.float64)))

    @property
    def centre_of_mass(self) -> np.ndarray:
        """(3,) centre of mass estimate in `base` [m]: the mesh's volume centroid when it is watertight, else
        the box centre (uniform density)."""
        if self.mesh is not None and getattr(self.mesh, "is_watertight", False):
            return np.asarray(self.mesh.center_mass, dtype=np.float64)
        return np.asarray(self.pose.t, dtype=np.float64)


@dataclass(frozen=True)
class GraspConfig:
    """Settings of grasp synthesis, collision checking and ranking.

    Attributes:
        approach_offset_m: the pre-grasp pose is this far back along the approach (tcp -z) [m]; the gripper is
            collision-checked swept over that distance.
        lift_m: the retreat pose is the grasp lifted this far along the support normal (base +z without a
            support plane) [m].
        clearance_m: free space left between each open pad and the object before closing, when the stroke
            allows [m] (the opening is width + 2 clearance, at most the stroke).
        min_clearance_m: the least such space for a grasp to be kept (narrower: rejected as "stroke") [m].
        palm_clearance_m: the palm stays this far from the object's extent along the approach [m].
        support_clearance_m: every gripper part stays this far above the support plane [m].
        fingertip_contact_margin_m: a parallel-jaw candidate that dips below the support moves back along its
            approach until it clears it, when each contact stays at least this far inside the pad's lower
            edge (an object lower than a pad, held by the fingertips; negative: never moved) [m].
        friction_coefficient: pad-object friction used by the antipodal friction-cone test [-].
        approach_tilts_deg: tilts of box approaches away from the box axes, in the plane normal to the
            closing direction [deg].
        n_slide: grasp positions along each face (odd: the centre is one of them).
        depth_steps_m: extra depths (shallower than the deepest allowed) tried for each box grasp [m].
        mesh_samples: surface points sampled on the mesh for antipodal pairs.
        antipodal_pairs: best antipodal contact pairs kept before approach directions are added.
        antipodal_approaches_deg: rotations of the approach about the closing axis, from the one nearest
            top-down [deg].
        suction_grid: grid positions per face side for suction (odd).
        suction_safety_factor: payload margin of the suction cup [-].
        voxel_size_m: edge of the voxel boxes the observed points are turned into [m].
        target_margin_m: observed points within the target's box grown by this are the target's own [m].
        support_band_m: observed points lower than this above the support plane are the support itself [m].
        max_candidates: candidates kept (best quality first) before checking.
        max_grasps: feasible grasps returned; the arm-link check runs in rank order until this many passed.
        arm_branches: IK branches tried (nearest the seed first) before a candidate is rejected for the arm.
        exhaustive: check the arm links of every candidate (slower; exact per-reason counts).
        joint_distance_weight: ranking penalty per radian of joint distance from the seed (score units).
        seed: RNG seed of the surface sampling.
    """

    approach_offset_m: float = 0.10
    lift_m: float = 0.10
    clearance_m: float = 0.01
    min_clearance_m: float = 0.004
    palm_clearance_m: float = 0.005
    support_clearance_m: float = 0.003
    fingertip_contact_margin_m: float = 0.003
    friction_coefficient: float = 0.5
    approach_tilts_deg: tuple[float, ...] = (0.0, -30.0, 30.0)
    n_slide: int = 3
    depth_steps_m: tuple[float, ...] = (0.0, 0.015)
    mesh_samples: int = 300
    antipodal_pairs: int = 60
    antipodal_approaches_deg: tuple[float, ...] = (0.0, -45.0, 45.0, -90.0, 90.0)
    suction_grid: int = 3
    suction_safety_factor: float = 2.0
    voxel_size_m: float = 0.01
    target_margin_m: float = 0.015
    support_band_m: float = 0.01
    max_candidates: int = 500
    max_grasps: int = 10
    arm_branches: int = 2
    exhaustive: bool = False
    joint_distance_weight: float = 0.01
    seed: int = 0

    def __post_init__(self) -> None:
        positive = {
            "approach_offset_m": self.approach_offset_m,
            "friction_coefficient": self.friction_coefficient,
            "voxel_size_m": self.voxel_size_m,
            "suction_safety_factor": self.suction_safety_factor,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise InvalidInputError(f"GraspConfig.{name} must be finite and > 0, got {value!r}")
        non_negative = {
            "lift_m": self.lift_m,
            "clearance_m": self.clearance_m,
            "min_clearance_m": self.min_clearance_m,
            "palm_clearance_m": self.palm_clearance_m,
            "support_clearance_m": self.support_clearance_m,
            "target_margin_m": self.target_margin_m,
            "support_band_m": self.support_band_m,
            "joint_distance_weight": self.joint_distance_weight,
        }
        for name, value in non_negative.items():
            if not (math.isfinite(value) and value >= 0):
                raise InvalidInputError(f"GraspConfig.{name} must be finite and >= 0, got {value!r}")
        margin = self.fingertip_contact_margin_m
        if not math.isfinite(margin):
            raise InvalidInputError(f"GraspConfig.fingertip_contact_margin_m must be finite, got {margin!r}")
        counts = ["n_slide", "mesh_samples", "antipodal_pairs", "suction_grid", "max_candidates"]
        counts += ["max_grasps", "arm_branches"]
        for name in counts:
            if int(getattr(self, name)) < 1:
                raise InvalidInputError(f"GraspConfig.{name} must be >= 1, got {getattr(self, name)!r}")


@dataclass(frozen=True, eq=False)
class Grasp:
    """One grasp, in `base`.

    Attributes:
        T_base_tcp: (4, 4) tcp pose at the grasp (tcp +z = approach, tcp y = closing direction for the jaws).
        T_base_pregrasp: (4, 4) tcp pose `approach_offset_m` back along the approach.
        T_base_retreat: (4, 4) tcp pose after the pick: the grasp lifted `lift_m` along the support normal.
        opening_m: pad-face distance to open to before the approach [m] (0 for suction).
        width_m: object width between the contacts [m] (0 for suction).
        quality: score in [0, 1] (higher is better) from the criteria in `reason`.
        reason: how the grasp was made and scored, in words.
        gripper: "parallel_jaw" or "suction".
        method: "box", "antipodal" or "suction".
        contacts: (K, 3) contact points [m] (2 pad contacts, or the cup centre).
        q: (6,) joint configuration at the grasp [rad] (closed form, nearest the seed, collision-free arm).
        score: ranking score (quality minus the joint-distance penalty).
    """

    T_base_tcp: np.ndarray
    T_base_pregrasp: np.ndarray
    T_base_retreat: np.ndarray
    opening_m: float
    width_m: float
    quality: float
    reason: str
    gripper: str
    method: str
    contacts: np.ndarray = field(repr=False)
    q: np.ndarray | None = None
    score: float = 0.0

    def __post_init__(self) -> None:
        for name in ("T_base_tcp", "T_base_pregrasp", "T_base_retreat", "contacts"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        if self.q is not None:
            object.__setattr__(self, "q", _readonly(self.q))

    @property
    def approach(self) -> np.ndarray:
        """(3,) unit approach direction in `base` (tcp +z)."""
        return self.T_base_tcp[:3, 2].copy()


@dataclass(frozen=True, eq=False)
class GraspPlan:
    """Feasible grasps, best first, with the bookkeeping of what was rejected and why.

    Iterating, indexing and `len` go over `grasps`.

    Attributes:
        grasps: feasible grasps, best (highest score) first.
        rejected: {reason: count} of candidates rejected; each candidate counts once, for the first check it
            failed, checks in the order stroke, support, payload, suction_not_flat, ik, collision_*,
            arm_collision.
        n_candidates: candidates generated (after the `max_candidates` cap).
        n_unchecked: candidates that passed every check but the arm-link one, which was not run on them
            because `max_grasps` were found first (0 with `exhaustive`).
        timings_ms: wall time of each stage [ms].
    """

    grasps: tuple[Grasp, ...]
    rejected: dict[str, int]
    n_candidates: int
    n_unchecked: int
    timings_ms: dict[str, float]

    def __iter__(self) -> Iterator[Grasp]:
        return iter(self.grasps)

    def __len__(self) -> int:
        return len(self.grasps)

    def __getitem__(self, i: int) -> Grasp:
        return self.grasps[i]

    @property
    def best(self) -> Grasp:
        return self.grasps[0]
