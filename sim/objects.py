"""Object assets: a procedural library of shape families and meshes loaded from OBJ/STL files.

Every asset lives in its canonical frame (DESIGN.md): origin at the centre of the amodal box, +y the object's
up (against gravity in its natural resting pose), metres. Its ground-truth size is exactly the axis-aligned
extents of the mesh in that frame, so a 9-DoF box (R, t, size) built from a body pose bounds the mesh with no
slack.

Families and their frames (docs/sim.md has the full table):

========  ==========================================================  ===============
family    shape and frame                                             symmetry
========  ==========================================================  ===============
box       product box (tea, cereal), upright                          box
carton    shipping carton, closed flaps                               box
can       drink or food can with rims; NOCS frame, axis +y            y_continuous
bottle    body, shoulder, neck, cap; NOCS frame, axis +y              y_continuous
bowl      open bowl with a foot ring; NOCS frame, axis +y             y_continuous
mug       open mug with handle; NOCS frame, handle along +x           none
cup       tapered paper/plastic cup, open top, axis +y                y_continuous
laptop    open laptop; NOCS-style: hinge along x, keyboard to +z      none
camera    body, lens along +z, grip at -x, viewfinder hump on top     none
ball      sphere                                                      spherical
tube      hollow cardboard tube lying down, axis along x              x_continuous
sack      filled sack lying flat (flour, grain), length along x       none
parcel    irregular, bulged soft parcel, length along x               none
========  ==========================================================  ===============

Symmetry tags: ``none``; ``y_continuous`` (any rotation about canonical y); ``x_continuous`` (any rotation
about x, and the 180 degree end-over-end flip); ``box`` (the 180 degree rotations about x, y and z);
``spherical`` (any rotation).

Physics: each asset also carries convex collision parts (a hull per part; the mug handle is split into several
hulls so the handle has a hole; the open containers, bowl, cup and mug, are hollow: a base disc and their wall
in angular sectors, so a finger fits inside and a rim can be gripped). Visual meshes are watertight part by
part so MuJoCo can compute volumes.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError

__all__ = [
    "COLLISION_MODELS",
    "FAMILIES",
    "NOCS_CATEGORIES",
    "SYMMETRIES",
    "ObjectAsset",
    "ObjectFamily",
    "load_mesh_object",
    "make_object",
    "sample_params",
]

log = logging.getLogger(__name__)

#: How a loaded mesh collides (`load_mesh_object`): its whole convex hull, or its convex decomposition.
COLLISION_MODELS = ("hull", "decompose")

#: The six NOCS categories: their canonical frames follow NOCS (+y up; mug handle along +x).
NOCS_CATEGORIES = ("bottle", "bowl", "camera", "can", "laptop", "mug")

#: Symmetry tags an asset may carry (see the module docstring).
SYMMETRIES = ("none", "y_continuous", "x_continuous", "box", "spherical")

#: Tessellation: segments around a body of revolution. 48 keeps the chord error of a 5 cm radius below
#: 0.11 mm (r (1 - cos(pi / 48))), far under one pixel at working distances.
_SECTIONS = 48
#: Angular sectors of the convex pieces of a hollow wall (`_shell_hulls`): a 24-gon's chord is within
#: r (1 - cos(pi / 24)) = 0.9 mm of a 10 cm radius, less than a wall's thickness.
_SHELL_SECTORS = 24


@dataclass(frozen=True, eq=False)
class ObjectAsset:
    """One object, in its canonical frame (origin at the amodal box centre, +y up, metres).

    Attributes:
        category: family name ("mug") or the category given for a mesh file.
        parts: visual meshes, each watertight where the family allows; together they are the object.
        collision: convex meshes for contact (MuJoCo takes each one's convex hull).
        size: (3,) float64 full extents along x, y, z [m]: exactly the extents of the union of `parts`.
        symmetry: one of `SYMMETRIES`.
        params: the family parameters the shape was built from (SI units), or {"scale_*"} for a mesh file.
        source: "procedural:<family>" or the mesh file path.
    """

    category: str
    parts: tuple[trimesh.Trimesh, ...]
    collision: tuple[trimesh.Trimesh, ...]
    size: np.ndarray
    symmetry: str
    params: Mapping[str, float] = field(default_factory=dict)
    source: str = ""

    @property
    def mesh(self) -> trimesh.Trimesh:
        """All visual parts as one mesh (canonical frame, metres)."""
        return trimesh.util.concatenate(list(self.parts))


@dataclass(frozen=True)
class ObjectFamily:
    """A procedural shape family: parameter ranges [SI units] and a builder from parameters to parts."""

    name: str
    ranges: Mapping[str, tuple[float, float]]
    symmetry: str
    prompt: str
    build: Callable[[Mapping[str, float]], tuple[list[trimesh.Trimesh], list[trimesh.Trimesh]]]
    #: Parameters that must be whole numbers (seeds of irregular shapes); drawn as integers.
    integer_params: tuple[str, ...] = ()


# ------------------------------------------------------------------------------------------------------------
# Mesh helpers


def _rot_z_to_y() -> np.ndarray:
    """(4, 4) rotation of -90 deg about x: maps +z onto +y (trimesh builds solids of revolution about z)."""
    return trimesh.transformations.rotation_matrix(-math.pi / 2.0, [1.0, 0.0, 0.0])


def _revolve_y(profile_r_y: Sequence[Sequence[float]], sections: int = _SECTIONS) -> trimesh.Trimesh:
    """Solid of revolution about +y of a closed (radius, height) profile [m]; watertight if the profile is."""
    pts = np.asarray(profile_r_y, dtype=np.float64)
    if not np.allclose(pts[0], pts[-1]):
        pts = np.vstack([pts, pts[:1]])
    mesh = trimesh.creation.revolve(pts, sections=sections)
    mesh.apply_transform(_rot_z_to_y())
    if mesh.volume < 0:  # the profile's winding decides the normals' side
        mesh.invert()
    return mesh


def _box(extents: Sequence[float], centre: Sequence[float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=np.asarray(extents, dtype=np.float64))
    mesh.apply_translation(np.asarray(centre, dtype=np.float64))
    return mesh


def _sweep_circle(
    path: np.ndarray, radius: float, binormal: np.ndarray, sections: int = 16
) -> trimesh.Trimesh:
    """A closed tube of the given radius [m] along a planar (N, 3) path whose plane normal is `binormal`."""
    n = len(path)
    tangents = np.gradient(path, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = np.cross(binormal, tangents)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    alpha = np.linspace(0.0, 2.0 * math.pi, sections, endpoint=False)
    ring = np.cos(alpha)[None, :, None] * normals[:, None, :] + np.sin(alpha)[None, :, None] * binormal
    verts = (path[:, None, :] + radius * ring).reshape(-1, 3)
    faces = []
    for i in range(n - 1):
        for j in range(sections):
            a, b = i * sections + j, i * sections + (j + 1) % sections
            c, d = a + sections, b + sections
            faces += [[a, b, d], [a, d, c]]
    start, end = len(verts), len(verts) + 1
    verts = np.vstack([verts, path[0], path[-1]])
    last = (n - 1) * sections
    for j in range(sections):
        faces.append([start, (j + 1) % sections, j])
        faces.append([end, last + j, last + (j + 1) % sections])
    mesh = trimesh.Trimesh(verts, np.asarray(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _convex_solid(vertices: np.ndarray, polygons: Sequence[Sequence[int]]) -> trimesh.Trimesh:
    """A convex polyhedron from its vertices (V, 3) and its faces as vertex-index polygons (any winding):
    each face is turned to face away from the centroid (right for a convex solid) and fan-triangulated."""
    v = np.asarray(vertices, dtype=np.float64)
    centre = v.mean(axis=0)
    tris = []
    for poly in polygons:
        f = list(poly)
        n = np.cross(v[f[1]] - v[f[0]], v[f[2]] - v[f[0]])
        if n @ (v[f].mean(axis=0) - centre) < 0:
            f = f[::-1]
        tris += [[f[0], f[k], f[k + 1]] for k in range(1, len(f) - 1)]
    mesh = trimesh.Trimesh(v, np.asarray(tris), process=False)
    mesh.metadata["convex"] = True  # by construction: `_finish` need not test it
    return mesh


def _shell_hulls(
    base: Sequence[float], walls: Sequence[Sequence[Sequence[float]]], sectors: int = _SHELL_SECTORS
) -> list[trimesh.Trimesh]:
    """Convex collision pieces of a hollow solid of revolution about +y.

    `base` (r0, y0, r1, y1) is the base disc, a frustum of radius r0 at height y0 and r1 at y1 [m]. Each wall
    polygon is a convex (radius, height) polygon of the profile off the axis [m], cut into `sectors` angular
    sectors, each piece the polygon swept between the sector's two bounding angles (a prism with flat sides).
    A bowl, cup or mug built from them is hollow as the real one is, where the convex hull of the whole
    part would be a solid lid over the opening (no finger fits inside, a rim cannot be gripped).
    """
    from scipy.spatial import ConvexHull

    r0, y0, r1, y1 = (float(x) for x in base)
    phi = np.linspace(0.0, 2.0 * math.pi, _SECTIONS, endpoint=False)
    rings = [
        np.stack([r * np.cos(phi), np.full_like(phi, y), r * np.sin(phi)], axis=1)
        for r, y in ((r0, y0), (r1, y1))
    ]
    n = _SECTIONS
    sides = [[k, (k + 1) % n, n + (k + 1) % n, n + k] for k in range(n)]
    out = [_convex_solid(np.vstack(rings), [list(range(n)), list(range(n, 2 * n)), *sides])]
    for poly in walls:
        pts = np.asarray(poly, dtype=np.float64)
        pts = pts[ConvexHull(pts).vertices]  # a band of a curved wall: its 2-D hull (within the sagitta)
        m = len(pts)
        for k in range(sectors):
            a, b = np.array([k, k + 1]) * 2.0 * math.pi / sectors
            v = np.vstack(
                [
                    np.stack([pts[:, 0] * math.cos(a), pts[:, 1], pts[:, 0] * math.sin(a)], axis=1),
                    np.stack([pts[:, 0] * math.cos(b), pts[:, 1], pts[:, 0] * math.sin(b)], axis=1),
                ]
            )
            quads = [[i, (i + 1) % m, m + (i + 1) % m, m + i] for i in range(m)]
            out.append(_convex_solid(v, [list(range(m)), list(range(m, 2 * m)), *quads]))
    return out


def _smooth_noise(points: np.ndarray, seed: int, n_waves: int = 6) -> np.ndarray:
    """Smooth scalar field in [-1, 1] on (N, 3) unit-scale points: a sum of random low-frequency waves."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(n_waves, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = rng.uniform(1.0, 3.0, size=n_waves)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=n_waves)
    field_ = np.sin((points @ dirs.T) * freq * math.pi + phase).sum(axis=1)
    return field_ / n_waves


# ------------------------------------------------------------------------------------------------------------
# Family builders: each returns (visual parts, collision parts) in an arbitrary frame; `_finish` recentres.

Parts = tuple[list[trimesh.Trimesh], list[trimesh.Trimesh]]


def _build_box(p: Mapping[str, float]) -> Parts:
    box = _box([p["width_m"], p["height_m"], p["depth_m"]])
    return [box], [box]


def _build_can(p: Mapping[str, float]) -> Parts:
    r, h = p["radius_m"], p["height_m"]
    rim = min(0.004, 0.05 * h)  # a real can's seam rim, a few millimetres
    profile = [(0, 0), (0.9 * r, 0), (r, rim), (r, h - rim), (0.93 * r, h), (0, h)]
    can = _revolve_y(profile)
    return [can], [can]


def _build_bottle(p: Mapping[str, float]) -> Parts:
    r, h = p["radius_m"], p["height_m"]
    rn = p["neck_ratio"] * r
    y_sh = p["shoulder_ratio"] * h  # where the shoulder starts
    y_neck = y_sh + 0.6 * (h - y_sh)  # shoulder ends, neck begins
    y_cap = h - min(0.022, 0.12 * h)  # cap: about 2 cm
    rc = min(rn * 1.12, r)
    profile = [(0, 0), (0.95 * r, 0), (r, 0.01 * h), (r, y_sh)]
    for s in np.linspace(0.15, 0.85, 5):  # rounded shoulder
        profile.append((rn + (r - rn) * math.cos(s * math.pi / 2.0), y_sh + (y_neck - y_sh) * s))
    profile += [(rn, y_neck), (rn, y_cap), (rc, y_cap), (rc, h), (0, h)]
    bottle = _revolve_y(profile)
    return [bottle], [bottle]


def _build_bowl(p: Mapping[str, float]) -> Parts:
    R, h, t = p["radius_m"], p["height_m"], p["wall_m"]
    rf = p["foot_ratio"] * R
    outer, inner = [], []
    for s in np.linspace(0.0, 1.0, 12):
        # superellipse-like wall: vertical-ish near the rim, flat near the foot
        outer.append((rf + (R - rf) * math.sin(s * math.pi / 2.0), h * (1.0 - math.cos(s * math.pi / 2.0))))
    ri_f = max(rf - t, 0.3 * rf)
    for s in np.linspace(1.0, 0.0, 12):
        inner.append(
            (
                ri_f + (R - t - ri_f) * math.sin(s * math.pi / 2.0),
                t + (h - t) * (1 - math.cos(s * math.pi / 2)),
            )
        )
    profile = [(0, 0), *outer, (R, h), (R - t, h), *inner, (0, t)]
    bowl = _revolve_y(profile)
    # Collision: hollow. The base disc, and the wall in 4 bands of the profile (outer and inner samples at
    # the same s face each other), each band cut into sectors (`_shell_hulls`).
    inner_up = inner[::-1]  # s from 0 (foot) to 1 (rim), as `outer`
    bands = [[*outer[a : b + 1], *inner_up[a : b + 1][::-1]] for a, b in ((0, 3), (3, 6), (6, 9), (9, 11))]
    return [bowl], _shell_hulls((rf, 0.0, ri_f, t), bands)


def _build_cup(p: Mapping[str, float]) -> Parts:
    rb, rt, h, t = p["bottom_radius_m"], p["top_radius_m"], p["height_m"], p["wall_m"]
    tb = max(2.0 * t, 0.004)  # base thicker than the wall
    profile = [(0, 0), (rb, 0), (rt, h), (rt - t, h), (rb - t + (rt - rb) * tb / h, tb), (0, tb)]
    cup = _revolve_y(profile)
    r_out = rb + (rt - rb) * tb / h  # the outer wall at the base's top
    wall = [(r_out - t, tb), (r_out, tb), (rt, h), (rt - t, h)]
    return [cup], _shell_hulls((rb, 0.0, r_out, tb), [wall])  # hollow, as the cup is


def _build_mug(p: Mapping[str, float]) -> Parts:
    r, h, t = p["radius_m"], p["height_m"], p["wall_m"]
    tb = max(1.5 * t, 0.006)
    body = _revolve_y([(0, 0), (r, 0), (r, h), (r - t, h), (r - t, tb), (0, tb)])
    # Handle: half an ellipse in the x-y plane on the +x side; its ends sink into the wall (x = r - t/2).
    a = p["handle_height_ratio"] * h / 2.0
    reach = p["handle_reach_m"]
    rho = p["handle_radius_m"]
    phi = np.linspace(-math.pi / 2.0, math.pi / 2.0, 25)
    path = np.stack(
        [r - t / 2.0 + reach * np.cos(phi), h / 2.0 + a * np.sin(phi), np.zeros_like(phi)], axis=1
    )
    handle = _sweep_circle(path, rho, binormal=np.array([0.0, 0.0, 1.0]))
    # Collision: the body hollow (base and wall sectors, `_shell_hulls`) plus the handle cut into 4 convex-ish
    # pieces, so the handle keeps its hole.
    pieces = []
    for k in range(4):
        sub = path[k * 6 : k * 6 + 7]
        pieces.append(_sweep_circle(sub, rho, binormal=np.array([0.0, 0.0, 1.0]), sections=8).convex_hull)
    shell = _shell_hulls((r, 0.0, r, tb), [[(r - t, tb), (r, tb), (r, h), (r - t, h)]])
    return [body, handle], [*shell, *pieces]


def _build_laptop(p: Mapping[str, float]) -> Parts:
    w, d, tb, ts = p["width_m"], p["depth_m"], p["base_thickness_m"], p["screen_thickness_m"]
    beta = math.radians(p["opening_deg"] - 90.0)  # lean of the screen behind the vertical
    base = _box([w, tb, d], centre=[0.0, tb / 2.0, d / 2.0])  # hinge line at z = 0, keyboard towards +z
    screen = _box([w, d, ts], centre=[0.0, d / 2.0, -ts / 2.0])  # upright screen standing on the hinge
    lean = trimesh.transformations.rotation_matrix(-beta, [1.0, 0.0, 0.0])  # tilt backwards, towards -z
    screen.apply_transform(lean)
    screen.apply_translation([0.0, tb, 0.0])
    return [base, screen], [base, screen]


def _build_camera(p: Mapping[str, float]) -> Parts:
    w, h, d = p["width_m"], p["height_m"], p["depth_m"]
    rl, ll = p["lens_radius_m"], p["lens_length_m"]
    body = _box([w, h, d])
    lens = trimesh.creation.cylinder(radius=rl, height=ll, sections=_SECTIONS)  # axis along z
    lens.apply_translation([0.1 * w, -0.05 * h, d / 2.0 + ll / 2.0 - 1e-4])
    grip = _box([0.22 * w, 0.92 * h, 0.35 * d], centre=[-0.39 * w, -0.04 * h, d / 2.0 + 0.175 * d - 1e-4])
    hump = _box([0.3 * w, 0.25 * h, 0.7 * d], centre=[0.1 * w, h / 2.0 + 0.125 * h - 1e-4, 0.0])
    parts = [body, lens, grip, hump]
    return parts, parts


def _build_ball(p: Mapping[str, float]) -> Parts:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=p["radius_m"])
    return [ball], [ball]


def _build_tube(p: Mapping[str, float]) -> Parts:
    r, L, t = p["radius_m"], p["length_m"], p["wall_m"]
    tube = trimesh.creation.annulus(r_min=r - t, r_max=r, height=L, sections=_SECTIONS)  # axis along z
    tube.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2.0, [0.0, 1.0, 0.0]))  # z -> x
    return [tube], [tube.convex_hull]


def _build_sack(p: Mapping[str, float]) -> Parts:
    L, W, T = p["length_m"], p["width_m"], p["thickness_m"]
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[24, 32])
    v = sphere.vertices
    # A filled sack is a flattened superellipsoid (boxy in plan, round in section) with lumps.
    e = 0.5
    sv = np.sign(v) * np.abs(v) ** e
    sv[:, 1] = v[:, 1]  # round in the vertical section
    lumps = 1.0 + p["lumpiness"] * _smooth_noise(v, int(p["seed"]))
    sv = sv * lumps[:, None]
    sv *= np.array([L / 2.0, T / 2.0, W / 2.0])
    sack = trimesh.Trimesh(sv, sphere.faces, process=True)
    return [sack], [sack.convex_hull]


def _build_parcel(p: Mapping[str, float]) -> Parts:
    L, H, W = p["length_m"], p["height_m"], p["width_m"]
    box = trimesh.creation.box(extents=[2.0, 2.0, 2.0]).subdivide().subdivide().subdivide()
    v = box.vertices.copy()
    # Faces bulge outwards in their middle (soft wrapping), plus a smooth random dent field.
    bulge = p["bulge"] * (1.0 - (v**2).sum(axis=1) / 3.0)  # 2/3 of `bulge` at face centres, 0 at corners
    noise = p["dent"] * _smooth_noise(v, int(p["seed"]))
    v = v * (1.0 + bulge + noise)[:, None]
    v *= np.array([L / 2.0, H / 2.0, W / 2.0])
    parcel = trimesh.Trimesh(v, box.faces, process=True)
    return [parcel], [parcel.convex_hull]


FAMILIES: dict[str, ObjectFamily] = {
    f.name: f
    for f in (
        ObjectFamily(
            "box",
            {"width_m": (0.05, 0.20), "height_m": (0.06, 0.28), "depth_m": (0.03, 0.10)},
            "box",
            "box",
            _build_box,
        ),
        ObjectFamily(
            "carton",
            {"width_m": (0.20, 0.60), "height_m": (0.12, 0.40), "depth_m": (0.15, 0.40)},
            "box",
            "cardboard carton",
            _build_box,
        ),
        ObjectFamily(
            "can", {"radius_m": (0.026, 0.05), "height_m": (0.07, 0.17)}, "y_continuous", "can", _build_can
        ),
        ObjectFamily(
            "bottle",
            {
                "radius_m": (0.025, 0.045),
                "height_m": (0.15, 0.32),
                "neck_ratio": (0.30, 0.45),
                "shoulder_ratio": (0.50, 0.72),
            },
            "y_continuous",
            "bottle",
            _build_bottle,
        ),
        ObjectFamily(
            "bowl",
            {
                "radius_m": (0.06, 0.12),
                "height_m": (0.04, 0.09),
                "wall_m": (0.004, 0.008),
                "foot_ratio": (0.35, 0.55),
            },
            "y_continuous",
            "bowl",
            _build_bowl,
        ),
        ObjectFamily(
            "mug",
            {
                "radius_m": (0.035, 0.05),
                "height_m": (0.08, 0.12),
                "wall_m": (0.004, 0.007),
                "handle_height_ratio": (0.45, 0.7),
                "handle_reach_m": (0.022, 0.035),
                "handle_radius_m": (0.005, 0.008),
            },
            "none",
            "mug",
            _build_mug,
        ),
        ObjectFamily(
            "cup",
            {
                "bottom_radius_m": (0.022, 0.032),
                "top_radius_m": (0.035, 0.048),
                "height_m": (0.07, 0.12),
                "wall_m": (0.0015, 0.003),
            },
            "y_continuous",
            "cup",
            _build_cup,
        ),
        ObjectFamily(
            "laptop",
            {
                "width_m": (0.28, 0.38),
                "depth_m": (0.19, 0.26),
                "base_thickness_m": (0.012, 0.022),
                "screen_thickness_m": (0.005, 0.009),
                "opening_deg": (95.0, 130.0),
            },
            "none",
            "laptop",
            _build_laptop,
        ),
        ObjectFamily(
            "camera",
            {
                "width_m": (0.10, 0.14),
                "height_m": (0.06, 0.09),
                "depth_m": (0.035, 0.06),
                "lens_radius_m": (0.022, 0.035),
                "lens_length_m": (0.025, 0.08),
            },
            "none",
            "camera",
            _build_camera,
        ),
        ObjectFamily("ball", {"radius_m": (0.03, 0.11)}, "spherical", "ball", _build_ball),
        ObjectFamily(
            "tube",
            {"radius_m": (0.02, 0.05), "length_m": (0.15, 0.45), "wall_m": (0.002, 0.005)},
            "x_continuous",
            "cardboard tube",
            _build_tube,
        ),
        ObjectFamily(
            "sack",
            {
                "length_m": (0.30, 0.60),
                "width_m": (0.20, 0.40),
                "thickness_m": (0.06, 0.15),
                "lumpiness": (0.0, 0.08),
                "seed": (0, 1_000_000),
            },
            "none",
            "sack",
            _build_sack,
            integer_params=("seed",),
        ),
        ObjectFamily(
            "parcel",
            {
                "length_m": (0.15, 0.50),
                "height_m": (0.06, 0.25),
                "width_m": (0.10, 0.35),
                "bulge": (0.0, 0.12),
                "dent": (0.0, 0.05),
                "seed": (0, 1_000_000),
            },
            "none",
            "parcel",
            _build_parcel,
            integer_params=("seed",),
        ),
    )
}


def _family(name: str) -> ObjectFamily:
    try:
        return FAMILIES[name]
    except KeyError:
        raise UnknownNameError("object family", name, sorted(FAMILIES)) from None


def sample_params(family: str, rng: np.random.Generator) -> dict[str, float]:
    """Draw a family's parameters uniformly from its ranges (SI units)."""
    fam = _family(family)
    out: dict[str, float] = {}
    for key, (lo, hi) in fam.ranges.items():
        out[key] = (
            float(rng.integers(int(lo), int(hi))) if key in fam.integer_params else float(rng.uniform(lo, hi))
        )
    return out


def _finish(
    category: str,
    parts: list[trimesh.Trimesh],
    collision: list[trimesh.Trimesh],
    symmetry: str,
    params,
    source,
) -> ObjectAsset:
    """Recentre on the amodal box centre and freeze; size = the exact extents of the visual parts."""
    allv = np.vstack([m.vertices for m in parts])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    centre = (lo + hi) / 2.0
    parts = [m.copy() for m in parts]
    collision = [m.copy() if m.metadata.get("convex") or m.is_convex else m.convex_hull for m in collision]
    for m in (*parts, *collision):
        m.apply_translation(-centre)
    size = (hi - lo).astype(np.float64)
    size.setflags(write=False)
    return ObjectAsset(category, tuple(parts), tuple(collision), size, symmetry, dict(params), source)


def make_object(
    family: str,
    params: Mapping[str, float] | None = None,
    rng: np.random.Generator | None = None,
) -> ObjectAsset:
    """Build one procedural object in its canonical frame.

    Args:
        family: a name in `FAMILIES` ("mug", "can", ...).
        params: parameters [SI units]; any not given are drawn from the family's ranges with `rng`, or set to
            the middle of the range when `rng` is None.
        rng: seeded generator for missing parameters.

    Raises:
        UnknownNameError: unknown family. InvalidInputError: unknown or non-finite/non-positive parameter.
    """
    fam = _family(family)
    given = dict(params or {})
    unknown = sorted(set(given) - set(fam.ranges))
    if unknown:
        raise InvalidInputError(
            f"unknown parameter(s) {unknown} for object family {family!r}; accepted: {sorted(fam.ranges)}"
        )
    full: dict[str, float] = {}
    for key, (lo, hi) in fam.ranges.items():
        if key in given:
            value = float(given[key])
            if not math.isfinite(value) or (key not in fam.integer_params and value <= 0.0):
                raise InvalidInputError(
                    f"parameter {key!r} of {family!r} must be finite and > 0, got {value}"
                )
        elif rng is not None:
            value = (
                float(rng.integers(int(lo), int(hi)))
                if key in fam.integer_params
                else float(rng.uniform(lo, hi))
            )
        else:
            value = float(round((lo + hi) / 2.0)) if key in fam.integer_params else (lo + hi) / 2.0
        full[key] = value
    parts, collision = fam.build(full)
    return _finish(family, parts, collision, fam.symmetry, full, f"procedural:{family}")


_UP_AXES = {
    "y": np.eye(4),
    # z-up files (most CAD and scan exports): rotate -90 degrees about x so +z becomes +y.
    "z": trimesh.transformations.rotation_matrix(-math.pi / 2.0, [1.0, 0.0, 0.0]),
}


def load_mesh_object(
    path: str | Path,
    scale: ArrayLike = (1.0, 1.0, 1.0),
    up_axis: str = "y",
    category: str | None = None,
    symmetry: str = "none",
    collision: str = "hull",
) -> ObjectAsset:
    """Load an OBJ/STL/PLY mesh file as an object asset.

    The file's axes become the canonical axes after `up_axis` is turned onto +y; the origin moves to the
    centre of the axis-aligned box, and `scale` (3,) multiplies the canonical x, y, z [unitless]. The file's
    units must be metres (scale converts others: 0.001 for millimetres).

    `collision`: "hull" collides the object as the convex hull of the whole mesh (solid: a scanned cup cannot
    be gripped by its rim); "decompose" as the convex parts of its approximate convex decomposition
    (`sim.decompose.convex_parts`: hollow where the mesh is, cached on disk; needs CoACD).

    Raises:
        InvalidInputError: missing/unreadable file, empty mesh, bad scale, unknown symmetry.
        UnknownNameError: unknown up axis.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"mesh file {str(p)!r} does not exist")
    s = np.asarray(scale, dtype=np.float64).reshape(-1)
    if s.shape == (1,):
        s = np.repeat(s, 3)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InvalidInputError(f"scale must be a positive finite scalar or (3,), got {scale!r}")
    if up_axis not in _UP_AXES:
        raise UnknownNameError("up axis", up_axis, sorted(_UP_AXES))
    if symmetry not in SYMMETRIES:
        raise UnknownNameError("symmetry", symmetry, SYMMETRIES)
    if collision not in COLLISION_MODELS:
        raise UnknownNameError("collision model", collision, COLLISION_MODELS)
    try:
        loaded = trimesh.load(str(p), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise InvalidInputError(f"cannot read mesh file {str(p)!r}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InvalidInputError(f"mesh file {str(p)!r} holds no triangles")
    mesh = loaded.copy()
    mesh.apply_transform(_UP_AXES[up_axis])
    mesh.vertices = mesh.vertices * s
    # "grab_mug/model.obj" is a mug: generic file names take the folder's name
    default_category = p.parent.name if p.stem in ("model", "mesh") else p.stem
    cat = category or default_category
    params = {"scale_x": float(s[0]), "scale_y": float(s[1]), "scale_z": float(s[2])}
    if collision == "decompose":
        from sim.decompose import convex_parts

        hulls = convex_parts(mesh)
    else:
        hulls = [mesh.convex_hull]
    return _finish(cat, [mesh], hulls, symmetry, params, str(p))
