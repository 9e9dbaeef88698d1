"""`ShapePrior`: a canonical mesh in the unit box and the point cloud sampled from it; user CAD meshes.

The paper samples N_p = 5000 points uniformly on the generated mesh and normalises them into a unit
axis-aligned bounding box (sections 3.3 and 4.1). Here the mesh itself is normalised per axis so that its
bounding box is exactly [-0.5, 0.5]^3, and the points are sampled on that normalised mesh, so points, normals
and mesh always agree. The metric proportions the normalisation removes are kept in `typical_size_m`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from prompose_grasp.errors import InvalidInputError, UnknownNameError

__all__ = [
    "DEFAULT_N_POINTS",
    "SYMMETRIES",
    "UP_AXES",
    "ShapePrior",
    "from_mesh",
    "normalize_to_unit_box",
]

log = logging.getLogger(__name__)

#: Points sampled on a prior's surface (the paper's N_p, section 4.1).
DEFAULT_N_POINTS = 5000

#: Symmetry tags, as the simulator's assets use them (docs/sim.md), plus `y_2fold`:
#: `none`; `y_continuous` (any rotation about y); `x_continuous` (any rotation about x and the end-over-end
#: flip); `box` (the 180 degree turns about x, y and z); `spherical` (any rotation); `y_2fold` (the 180 degree
#: turn about y only: a pallet or an open crate, whose top and bottom differ).
SYMMETRIES = ("none", "y_continuous", "x_continuous", "box", "spherical", "y_2fold")

#: Rotations that turn a mesh whose up is the named axis into the canonical +y-up frame (right-handed).
UP_AXES: dict[str, np.ndarray] = {
    "y": np.eye(3),
    "-y": np.diag([1.0, -1.0, -1.0]),  # 180 degrees about x
    "z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # -90 degrees about x: +z -> +y
    "-z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),  # +90 degrees about x: -z -> +y
    "x": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),  # +90 degrees about z: +x -> +y
    "-x": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),  # -90 degrees about z: -x -> +y
}

#: Extents below this fraction of the largest extent make per-axis normalisation meaningless (a flat sheet
#: would be stretched by > 1e6 along its thin axis); real objects are far thicker than 1e-6 of their size.
_MIN_RELATIVE_EXTENT = 1e-6


@dataclass(frozen=True, eq=False)
class ShapePrior:
    """A canonical shape prior: mesh and surface samples in the unit box of the object frame.

    Frame: origin at the box centre, +y up (against gravity in the natural resting pose); families with a
    front fix +x / +z (docs/priors.md). Coordinates are unitless: the mesh's axis-aligned bounding box is
    exactly [-0.5, 0.5]^3 (each axis scaled on its own, as the paper normalises into a unit axis-aligned
    box), so `Pose9D.points_to_camera` maps them to metres with the estimated size.

    Attributes:
        name: family name ("mug"), "superquadric", or the mesh file's stem.
        source: "library:<family>", "superquadric", "user_mesh:<path>" or "hunyuan3d".
        mesh: the normalised mesh (treat as read-only; `mesh.copy()` before editing).
        points: (N, 3) float32 points sampled uniformly by area on `mesh` (seeded), N = 5000 by default.
        normals: (N, 3) float32 unit outward normals of the faces the points lie on.
        symmetry: one of `SYMMETRIES`.
        typical_size_m: (3,) float64 [m] full extents along x, y, z before normalisation: a family's typical
            size, a superquadric's fitted size, a CAD mesh's own extents (in the file's units).
        prompt: the text the prior was generated for ("" for a mesh passed directly).
        matched_text: the library description that matched the prompt best ("" when none was used).
        score: cosine similarity of prompt and `matched_text` (NaN when no text matching chose the prior).
    """

    name: str
    source: str
    mesh: trimesh.Trimesh
    points: np.ndarray
    normals: np.ndarray
    symmetry: str
    typical_size_m: np.ndarray
    prompt: str = ""
    matched_text: str = ""
    score: float = math.nan

    @property
    def aspect(self) -> np.ndarray:
        """(3,) float64 metric proportions: `typical_size_m` divided by its largest entry."""
        return self.typical_size_m / float(np.max(self.typical_size_m))

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])


def normalize_to_unit_box(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    """Scale and shift a mesh, each axis on its own, so that its bounding box is [-0.5, 0.5]^3.

    Args:
        mesh: any mesh with finite vertices and a non-zero extent along x, y and z.

    Returns:
        (unit_mesh, centre, extents): a new mesh; the (3,) float64 centre and full extents of the input's
        bounding box (input units). `unit = (v - centre) / extents`.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[0] < 4 or v.shape[1] != 3 or len(mesh.faces) == 0:
        raise InvalidInputError(f"mesh needs >= 4 vertices and >= 1 face, got {len(v)} and {len(mesh.faces)}")
    if not np.all(np.isfinite(v)):
        raise InvalidInputError("mesh vertices hold NaN or inf")
    lo, hi = v.min(axis=0), v.max(axis=0)
    extents = hi - lo
    if np.min(extents) <= _MIN_RELATIVE_EXTENT * np.max(extents):
        raise InvalidInputError(
            f"mesh is flat along an axis (extents {extents.tolist()}); per-axis normalisation to the unit "
            "box needs a non-zero thickness along x, y and z"
        )
    centre = (lo + hi) / 2.0
    unit_v = (v - centre) / extents
    # Remove the last rounding so the box is [-0.5, 0.5] exactly on the extreme vertices.
    unit_v[np.argmin(v, axis=0), [0, 1, 2]] = -0.5
    unit_v[np.argmax(v, axis=0), [0, 1, 2]] = 0.5
    unit = trimesh.Trimesh(unit_v, np.asarray(mesh.faces).copy(), process=False)
    return unit, centre, extents


def _sample_surface(mesh: trimesh.Trimesh, n_points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) float32 points uniform by area on `mesh` and (n, 3) float32 normals of their faces."""
    points, face_index = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[face_index]
    return (
        np.ascontiguousarray(points, dtype=np.float32),
        np.ascontiguousarray(normals, dtype=np.float32),
    )


def _check_n_points(n_points: int) -> int:
    if isinstance(n_points, bool) or not isinstance(n_points, int | np.integer) or n_points < 1:
        raise InvalidInputError(f"n_points must be a positive int, got {n_points!r}")
    return int(n_points)


def make_prior(
    mesh: trimesh.Trimesh,
    *,
    name: str,
    source: str,
    symmetry: str,
    n_points: int = DEFAULT_N_POINTS,
    seed: int = 0,
    prompt: str = "",
    matched_text: str = "",
    score: float = math.nan,
    typical_size_m: np.ndarray | None = None,
) -> ShapePrior:
    """Normalise `mesh` (canonical frame, +y up, any units) to the unit box and sample it into a `ShapePrior`.

    `typical_size_m` defaults to the mesh's own extents.
    """
    if symmetry not in SYMMETRIES:
        raise UnknownNameError("symmetry", symmetry, SYMMETRIES)
    n = _check_n_points(n_points)
    unit, _, extents = normalize_to_unit_box(mesh)
    points, normals = _sample_surface(unit, n, int(seed))
    size = np.array(extents if typical_size_m is None else typical_size_m, dtype=np.float64)
    if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size <= 0):
        raise InvalidInputError(f"typical_size_m must be (3,) positive finite metres, got {size!r}")
    for a in (points, normals, size):
        a.setflags(write=False)
    return ShapePrior(
        name=name,
        source=source,
        mesh=unit,
        points=points,
        normals=normals,
        symmetry=symmetry,
        typical_size_m=size,
        prompt=prompt,
        matched_text=matched_text,
        score=float(score),
    )


def _load_mesh(path: Path) -> trimesh.Trimesh:
    if not path.is_file():
        raise InvalidInputError(f"mesh file {str(path)!r} does not exist")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise InvalidInputError(
            f"could not read mesh {str(path)!r} ({exc}); OBJ, STL, PLY, OFF, GLB are accepted"
        ) from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InvalidInputError(f"mesh file {str(path)!r} holds no triangles")
    return loaded


def from_mesh(
    mesh: str | Path | trimesh.Trimesh,
    up_axis: str = "y",
    *,
    name: str | None = None,
    symmetry: str = "none",
    n_points: int = DEFAULT_N_POINTS,
    seed: int = 0,
    prompt: str = "",
    source: str | None = None,
) -> ShapePrior:
    """A prior from a user CAD mesh (file or `trimesh.Trimesh`), in place of the text-retrieved one.

    Args:
        mesh: a mesh file (OBJ, STL, PLY, OFF, GLB; multi-part scenes are merged) or a `trimesh.Trimesh`.
            Units do not matter for the prior (it is normalised); metres make `typical_size_m` metric.
        up_axis: which of the mesh's axes is the object's up: "y", "z", "x", "-y", "-z", "-x" ("z" for
            most CAD exports). The mesh is turned so that axis becomes +y; the front is left as modelled.
        name: defaults to the file stem ("mesh" for an in-memory mesh).
        symmetry: one of `SYMMETRIES`; the caller knows the object's symmetry, it is not guessed.
        n_points, seed: surface samples and their seed.
        prompt: the text the mesh stands for, kept for the record.
        source: defaults to "user_mesh:<path>" ("user_mesh:<memory>" for an in-memory mesh).
    """
    if up_axis not in UP_AXES:
        raise UnknownNameError("up_axis", up_axis, UP_AXES)
    if isinstance(mesh, trimesh.Trimesh):
        tm = mesh.copy()
        label = "<memory>"
        default_name = "mesh"
    elif isinstance(mesh, str | Path):
        tm = _load_mesh(Path(mesh))
        label = str(mesh)
        default_name = Path(mesh).stem
    else:
        raise InvalidInputError(f"mesh must be a path or a trimesh.Trimesh, got {type(mesh).__name__}")
    T = np.eye(4)
    T[:3, :3] = UP_AXES[up_axis]
    tm.apply_transform(T)
    return make_prior(
        tm,
        name=name or default_name,
        source=source or f"user_mesh:{label}",
        symmetry=symmetry,
        n_points=n_points,
        seed=seed,
        prompt=prompt,
    )
