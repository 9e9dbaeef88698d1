"""Suction grasp candidates on the faces of the target's 9-DoF box.

Suction grasps. On each face of the box whose normal does not point down, on a grid of points where the whole
cup fits, nearest the projection of the centre of mass first; with a mesh, the face must be flat under the
cup (mesh samples within 3 mm of the face plane, normals within the cup's seal angle, covering the cup's
rim). Quality: 0.5 top-down, 0.4 offset from the centre of mass (the moment on the cup), 0.1 face size.
"""

from __future__ import annotations

import math

import numpy as np

from prompose_grasp.geometry.distance import cross
from prompose_grasp.grasp.candidates import Candidates, Reasons, stack_transforms, support_up
from prompose_grasp.grasp.grippers import SuctionCupGeometry
from prompose_grasp.grasp.types import GraspConfig, ObjectModel, Plane

__all__ = ["suction_grasps"]

#: Box axis names, in the reasons.
_AXES = "xyz"


def _flat_under_cups(
    samples: np.ndarray,
    sample_normals: np.ndarray,
    face_point: np.ndarray,
    normal: np.ndarray,
    centres: np.ndarray,
    radius: float,
    max_angle_deg: float,
    spacing: float,
) -> np.ndarray:
    """(G,) True where the cup centred at each of `centres` (G, 3) on the face plane (through `face_point`,
    normal `normal`) sits on flat mesh: mesh samples within 3 mm of the plane with normals within the seal
    angle cover the cup's centre and its rim (16 points), each probe within `spacing` of such a sample."""
    from scipy.spatial import cKDTree

    flat = (np.abs((samples - face_point) @ normal) <= 0.003) & (
        sample_normals @ normal >= math.cos(math.radians(max_angle_deg))
    )
    if not np.any(flat):
        return np.zeros(len(centres), dtype=bool)
    e1 = cross(normal, np.array([1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0]))
    e1 /= np.linalg.norm(e1)
    e2 = cross(normal, e1)
    ang = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    ring = np.vstack(
        [np.zeros(3), radius * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)]
    )  # (17, 3)
    probes = (centres[:, None, :] + ring[None]).reshape(-1, 3)
    d, _ = cKDTree(samples[flat]).query(probes)
    return np.all(d.reshape(len(centres), -1) <= spacing, axis=1)


def _mesh_is_the_box(target: ObjectModel) -> bool:
    """The target's mesh is its estimated box (a carton prior: closed, the box's bounds and volume): every
    face is then flat all over, and sampling it for flatness is not needed."""
    mesh = target.mesh
    V = np.asarray(mesh.vertices, dtype=np.float64)
    if len(V) > 64 or not getattr(mesh, "is_watertight", False):
        return False
    local = (V - target.pose.t) @ target.pose.R
    half = np.asarray(target.pose.size) / 2.0
    tol = 1e-6 * float(np.max(half))
    if np.any(np.abs(local.max(axis=0) - half) > tol) or np.any(np.abs(local.min(axis=0) + half) > tol):
        return False
    box_volume = float(np.prod(2.0 * half))
    return abs(abs(float(mesh.volume)) - box_volume) <= 1e-6 * box_volume


def suction_grasps(
    target: ObjectModel, cup: SuctionCupGeometry, config: GraspConfig, support: Plane | None = None
) -> Candidates:
    """Suction grasps on the faces of the target's box (see the module docstring)."""
    R, c, size = target.pose.R, target.pose.t, target.pose.size
    com = target.centre_of_mass
    up = support_up(support)
    r = cup.cup_radius_m
    samples = normals = None
    spacing = 0.0
    if target.mesh is not None and not _mesh_is_the_box(target):
        import trimesh

        n_samples = 4 * config.mesh_samples
        pts, fidx = trimesh.sample.sample_surface(target.mesh, n_samples, seed=config.seed)
        samples, normals = np.asarray(pts), np.asarray(target.mesh.face_normals)[fidx]
        # Mean spacing of the samples, doubled: a flat region covered by the samples has a sample this close.
        spacing = 2.0 * math.sqrt(float(target.mesh.area) / n_samples)
    rows_R: list[np.ndarray] = []
    rows_p: list[np.ndarray] = []
    rows_q: list[np.ndarray] = []
    pre: list[np.ndarray] = []
    faces: list[tuple[str, float, np.ndarray, int]] = []  # (face, tilt [deg], lateral offsets (G,), G)
    for m in range(3):
        others = [x for x in range(3) if x != m]
        for s in (1.0, -1.0):
            nrm = s * R[:, m]
            if nrm @ up < -0.5:  # the face the object stands on (or hangs below)
                continue
            face_c = c + nrm * size[m] / 2.0
            half = np.array([size[o] / 2.0 - r for o in others])
            if np.any(half < -1e-9):
                continue  # the cup does not fit on this face
            half = np.maximum(half, 0.0)
            # A g x g grid over the positions where the cup fits, plus the projection of the centre of mass;
            # nearest that projection first.
            com_proj = np.clip([(com - face_c) @ R[:, o] for o in others], -half, half)
            g = config.suction_grid
            us, vs = np.meshgrid(np.linspace(-half[0], half[0], g), np.linspace(-half[1], half[1], g))
            grid = np.vstack([com_proj[None], np.stack([us.ravel(), vs.ravel()], axis=1)])
            # Distinct rows in lexicographic order (np.unique(axis=0) without its structured-array sort).
            grid = np.round(grid, 9)
            grid = grid[np.lexsort((grid[:, 1], grid[:, 0]))]
            grid = grid[np.r_[True, np.any(grid[1:] != grid[:-1], axis=1)]]
            grid = grid[np.argsort(np.linalg.norm(grid - com_proj, axis=1), kind="stable")][: g * g]
            pts = face_c + grid[:, :1] * R[:, others[0]] + grid[:, 1:] * R[:, others[1]]  # (G, 3)
            if samples is not None and normals is not None:
                flat_ok = _flat_under_cups(
                    samples, normals, face_c, nrm, pts, r, cup.max_face_angle_deg, spacing
                )
            else:
                flat_ok = np.ones(len(pts), dtype=bool)
            lat = com - pts
            lateral = np.linalg.norm(lat - (lat @ nrm)[:, None] * nrm, axis=1)
            face_half_diag = math.hypot(size[others[0]], size[others[1]]) / 2.0
            a = -nrm
            top = 0.5 * (1.0 - float(a @ up))
            q = (
                0.5 * top
                + 0.4 * np.clip(1.0 - lateral / max(face_half_diag, 1e-9), 0.0, 1.0)
                + 0.1 * min(1.0, (2.0 * min(size[others[0]], size[others[1]])) / (8.0 * r))
            )
            payload = ""
            if target.mass_kg is not None:
                sideways = float(a @ up) > -0.7  # not top-down: the load is a shear on the lip
                limit = cup.max_payload_kg(config.suction_safety_factor, lateral_g=1.0 if sideways else 0.0)
                if target.mass_kg > limit:
                    payload = "payload"
            tilt = math.degrees(math.acos(float(np.clip(-a @ up, -1, 1))))
            x0 = R[:, others[0]]
            yaws = np.array([0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi])
            x = np.cos(yaws)[:, None] * x0 + np.sin(yaws)[:, None] * cross(a, x0)  # (4, 3)
            Rt = np.stack([x, cross(np.broadcast_to(a, x.shape), x), np.broadcast_to(a, x.shape)], axis=2)
            G = len(pts)
            rows_R.append(np.repeat(Rt, G, axis=0))  # rows: yaw-major, then grid point
            rows_p.append(np.tile(pts, (4, 1)))
            rows_q.append(np.tile(q, 4))
            status = np.where(flat_ok, "", "suction_not_flat").astype(object)
            if payload:
                status[:] = payload
            pre.append(np.tile(status, 4))
            faces.append((f"{'+' if s > 0 else '-'}{_AXES[m]}", tilt, lateral, G))
    n = sum(len(r) for r in rows_R)
    if n == 0:
        return Candidates.empty()
    mass = "mass unknown" if target.mass_kg is None else f"{target.mass_kg:.2f} kg"
    starts = np.cumsum([0] + [4 * f[3] for f in faces])

    def suction_reason(row: int) -> str:
        k = int(np.searchsorted(starts, row, side="right")) - 1
        face, tilt, lateral, G = faces[k]
        g = (row - int(starts[k])) % G
        return (
            f"suction: obj {face} face, {lateral[g] * 1e3:.0f} mm from the centre of mass, approach "
            f"{tilt:.0f} deg from top-down, {mass} (holds {cup.max_force_n:.0f} N)"
        )

    p_all = np.concatenate(rows_p)
    return Candidates(
        stack_transforms(np.concatenate(rows_R), p_all),
        np.zeros(n),
        np.zeros(n),
        np.stack([p_all, p_all], axis=1),
        np.clip(np.concatenate(rows_q), 0.0, 1.0),
        np.full(n, "suction", dtype=object),
        Reasons.lazy(suction_reason, n),
        np.zeros(n, dtype=bool),
        np.concatenate(pre),
    )
