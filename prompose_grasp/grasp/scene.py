"""The collision scene on python-fcl: support plane, other objects, observed points, the target, the arm.

One `CollisionScene` holds, in `base`:

- the support plane (an `fcl.Halfspace`, in its own manager: the arm's base links stand on it, so it is
  checked only against the links that must clear it, and against grippers analytically in the planner);
- every other object as its estimated box (`fcl.Box`) or scaled mesh (`fcl.BVHModel`), fixtures likewise;
- the observed point cloud without the target's own points and the support's, as voxel boxes: every occupied
  voxel becomes a cube, and all cubes together one `fcl.BVHModel` (12 triangles a cube; a cube overlapped by a
  gripper box is found because one of its triangles intersects or lies in the box);
- the target itself (separately: grasps must touch it, so only some checks include it).

Single queries (`collide_object`, `arm_hit`) go through fcl's `DynamicAABBTreeCollisionManager`
(broadphase). Batched queries (hundreds of gripper poses, or arm configurations, at once: `boxes_first_hits`,
`arm_hits_batch`) run their broadphase in numpy instead: world bounding boxes, then the separating-axis test
between each query's oriented box and each scene item's oriented bounding box (obstacle boxes, the oriented
bounds of meshes in their pose frame, 10 cm blocks of voxels). Box against box is decided there exactly (the
test is exact for boxes), a box against voxels by the same test against each voxel cube of the overlapping
blocks, and only the pairs left (a box or capsule against a mesh, a capsule against voxels or a box) go to
fcl's narrowphase, one `fcl.collide` each, skipping queries already known to collide. Every query reports
*what* was hit: the kind ("object", "fixture", "points", "target", "support") and the obstacle's name.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp.batch_ik import link_frames_batch
from prompose_grasp.grasp.synthesis import cross
from prompose_grasp.grasp.types import ObjectModel, Plane

__all__ = ["CollisionScene", "Hit", "obb_overlap", "segment_distance", "voxelize_points"]

log = logging.getLogger(__name__)

#: Edge of the blocks the voxel meshes are split into [m] (about a gripper box: tight block bounds let the
#: broadphase skip most blocks, and few voxels per block reach the exact per-voxel test).
_VOXEL_BLOCK_M = 0.10
#: Kinds of scene items of the numpy broadphase: a box decided exactly by the separating-axis test, a geometry
#: that needs fcl's narrowphase (mesh), a block of voxel cubes (decided per cube).
_EXACT_BOX, _NARROWPHASE, _VOXELS = 0, 1, 2
#: Slack of the separating-axis test [m] and of its near-parallel edge axes [-]: touching boxes overlap.
_SAT_EPS = 1e-12
#: A capsule whose segment is within this of its radius from a box [m] is left to fcl's narrowphase (the
#: numpy distance is exact to ~1e-10 m; fcl decides the touching cases).
_DISTANCE_BAND_M = 1e-7
#: Links that stand on the support (never checked against it).
_BASE_LINKS = ("base", "shoulder_link")

# Unit cube corners and triangles (outward winding) for voxel meshes.
_CUBE_V = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float64
)
_CUBE_F = np.array(
    [
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ],
    dtype=np.int64,
)  # fmt: skip


@dataclass(frozen=True)
class Hit:
    """What a query touched: `kind` ("object", "fixture", "points", "target", "support") and `name`."""

    kind: str
    name: str

    @property
    def reason(self) -> str:
        return f"collision_{self.kind}"


#: Placeholder result of a query that is not to be checked (never returned).
_MASK = Hit("masked", "")


def _transform(R: np.ndarray, t: np.ndarray) -> fcl.Transform:
    return fcl.Transform(np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(t, dtype=np.float64))


def _bvh(vertices: np.ndarray, faces: np.ndarray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(
        np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64)
    )
    model.endModel()
    return model


def voxelize_points(points: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """(M, 3) centres [m] of the occupied voxels of the grid of edge `voxel_size_m` aligned with the axes."""
    keys = np.unique(np.floor(points / voxel_size_m).astype(np.int64), axis=0)
    return (keys + 0.5) * voxel_size_m


def _object_geometry(obj: ObjectModel) -> tuple[fcl.CollisionGeometry, fcl.Transform]:
    if obj.mesh is not None:
        return _bvh(np.asarray(obj.mesh.vertices), np.asarray(obj.mesh.faces)), fcl.Transform()
    return fcl.Box(*obj.pose.size), _transform(obj.pose.R, obj.pose.t)


def _object_bounds(obj: ObjectModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(centre (3,), R (3, 3), half extents (3,), item kind): the object's box, or for a mesh the bounds of
    its vertices in the box frame (a mesh need not fit its estimated box)."""
    R = np.asarray(obj.pose.R, dtype=np.float64)
    if obj.mesh is None:
        return np.asarray(obj.pose.t, dtype=np.float64), R, np.asarray(obj.pose.size) / 2.0, _EXACT_BOX
    local = (np.asarray(obj.mesh.vertices, dtype=np.float64) - obj.pose.t) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    kind = _NARROWPHASE
    # A closed mesh inside its bounds with their volume is that box (a carton's prior): decided exactly.
    if len(local) <= 64 and getattr(obj.mesh, "is_watertight", False):
        box_volume = float(np.prod(hi - lo))
        if abs(abs(float(obj.mesh.volume)) - box_volume) <= 1e-6 * box_volume:
            kind = _EXACT_BOX
    return obj.pose.t + R @ ((lo + hi) / 2.0), R, (hi - lo) / 2.0, kind


def obb_overlap(
    ca: np.ndarray, Ra: np.ndarray, ha: np.ndarray, cb: np.ndarray, Rb: np.ndarray, hb: np.ndarray
) -> np.ndarray:
    """(P,) True where oriented boxes a and b overlap (touching counts): the separating-axis test over the
    15 axes (3 + 3 face normals, 9 edge pairs), exact for boxes.

    Args:
        ca, cb: (P, 3) centres [m]; Ra, Rb: (P, 3, 3) rotations (columns = box axes in the common frame);
        ha, hb: (P, 3) half extents [m]. Any of b's may be broadcast from (3,), (3, 3).
    """
    Rb = np.broadcast_to(Rb, Ra.shape)
    hb = np.broadcast_to(hb, ha.shape)
    R = np.matmul(np.swapaxes(Ra, 1, 2), Rb)  # b's axes in a's frame
    t = np.matmul(np.swapaxes(Ra, 1, 2), (cb - ca)[:, :, None])[:, :, 0]  # b's centre in a's frame
    A = np.abs(R) + _SAT_EPS
    ga = np.abs(t) - ha - np.matmul(A, hb[:, :, None])[:, :, 0]
    tb = np.matmul(np.swapaxes(R, 1, 2), t[:, :, None])[:, :, 0]
    gb = np.abs(tb) - np.matmul(np.swapaxes(A, 1, 2), ha[:, :, None])[:, :, 0] - hb
    sep = (ga[:, 0] > 0) | (ga[:, 1] > 0) | (ga[:, 2] > 0) | (gb[:, 0] > 0) | (gb[:, 1] > 0) | (gb[:, 2] > 0)
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = ha[:, i1] * A[:, i2, j] + ha[:, i2] * A[:, i1, j]
            rb = hb[:, j1] * A[:, i, j2] + hb[:, j2] * A[:, i, j1]
            sep |= np.abs(t[:, i2] * R[:, i1, j] - t[:, i1] * R[:, i2, j]) > ra + rb
    return ~sep


class CollisionScene:
    """Everything the gripper and the arm must not touch, as fcl objects in broadphase managers.

    Args:
        obstacles: other objects and fixtures (`ObjectModel` in `base`; the mesh is used when present).
        support: the support plane, or None.
        points_base: (N, 3) observed points in `base` [m], or None. Points inside the target's box grown by
            `target_margin_m`, and points less than `support_band_m` above the support, are dropped (they are
            the target and the support); the rest become voxel boxes of edge `voxel_size_m`.
        target: the object to grasp, or None.
        voxel_size_m, target_margin_m, support_band_m: see above [m].
        crop_radius_m: points farther than this from the base origin are dropped (out of reach) [m].
        robot_capsules: the arm's (and gripper's) capsules (name, p0, p1, radius) in `base` where the camera
            saw it; points within `robot_margin_m` of them are the robot itself and are dropped.

    Points inside an obstacle's box grown by one voxel are dropped too: the obstacle already stands for them.
    Obstacles entirely below the support plane are left out: the plane stands for them.
    """

    def __init__(
        self,
        obstacles: Sequence[ObjectModel] = (),
        support: Plane | None = None,
        points_base: ArrayLike | None = None,
        target: ObjectModel | None = None,
        voxel_size_m: float = 0.01,
        target_margin_m: float = 0.015,
        support_band_m: float = 0.01,
        crop_radius_m: float | None = None,
        robot_capsules: Sequence[tuple[str, np.ndarray, np.ndarray, float]] = (),
        robot_margin_m: float = 0.03,
    ):
        if support is not None and not isinstance(support, Plane):
            raise InvalidInputError(
                f"support must be a Plane (base frame) or None, got {type(support).__name__}"
            )
        self.support = support
        self.target = target
        self._labels: dict[int, Hit] = {}
        # Scene items of the numpy broadphase: fcl object, label, oriented bounds, kind, voxel centres.
        self._items: list[tuple[fcl.CollisionObject, Hit, np.ndarray | None]] = []
        bounds: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []
        objects = []
        for obs in obstacles:
            if not isinstance(obs, ObjectModel):
                raise InvalidInputError(f"obstacles must be ObjectModel values, got {type(obs).__name__}")
            if support is not None and float(np.max(support.height(obs.pose.corners()))) <= 0.0:
                continue  # entirely below the support plane: the plane already stands for it
            geom, tf = _object_geometry(obs)
            objects.append(self._register(geom, tf, Hit(obs.kind, obs.name)))
            self._items.append((objects[-1], Hit(obs.kind, obs.name), None))
            bounds.append(_object_bounds(obs))
        self.voxel_centres = np.zeros((0, 3))
        self.voxel_size_m = float(voxel_size_m)
        if points_base is not None:
            try:
                P = np.asarray(points_base, dtype=np.float64)
            except (TypeError, ValueError):
                raise InvalidInputError(
                    f"points_base must be an (N, 3) array of points [m], got {type(points_base).__name__}"
                ) from None
            if P.ndim != 2 or P.shape[1] != 3:
                raise InvalidInputError(f"points_base must have shape (N, 3) [m], got {P.shape}")
            P = P[np.all(np.isfinite(P), axis=1)]
            if crop_radius_m is not None:
                P = P[np.einsum("ij,ij->i", P, P) <= float(crop_radius_m) ** 2]
            if support is not None:
                P = P[support.height(P) >= support_band_m]
            # Voxelise first, then drop the voxels (by centre) explained by obstacles, the robot, the target:
            # the filters then run on thousands of centres rather than a frame's ~300k points.
            P = voxelize_points(P, self.voxel_size_m) if len(P) else P
            for obs in obstacles:
                local = (P - obs.pose.t) @ obs.pose.R
                P = P[~np.all(np.abs(local) <= obs.pose.size / 2.0 + voxel_size_m, axis=1)]
            for _, p0, p1, radius in robot_capsules:
                P = P[segment_distance(P, np.asarray(p0), np.asarray(p1)) > radius + robot_margin_m]
            if target is not None:
                local = (P - target.pose.t) @ target.pose.R
                inside = np.all(np.abs(local) <= target.pose.size / 2.0 + target_margin_m, axis=1)
                P = P[~inside]
            if len(P):
                self.voxel_centres = P
                # One mesh per 25 cm block of voxels: tight bounding boxes let the broadphase skip the blocks
                # a query is far from (one mesh for all would overlap every query's bounding box).
                blocks = np.floor(self.voxel_centres / _VOXEL_BLOCK_M).astype(np.int64)
                _, block_of = np.unique(blocks, axis=0, return_inverse=True)
                for b in range(int(block_of.max()) + 1):
                    C = self.voxel_centres[block_of.ravel() == b]
                    V = (C[:, None, :] + self.voxel_size_m * _CUBE_V[None]).reshape(-1, 3)
                    F = (np.arange(len(C))[:, None, None] * 8 + _CUBE_F[None]).reshape(-1, 3)
                    objects.append(
                        self._register(_bvh(V, F), fcl.Transform(), Hit("points", "observed points"))
                    )
                    lo, hi = C.min(axis=0) - voxel_size_m / 2.0, C.max(axis=0) + voxel_size_m / 2.0
                    self._items.append((objects[-1], Hit("points", "observed points"), C))
                    bounds.append(((lo + hi) / 2.0, np.eye(3), (hi - lo) / 2.0, _VOXELS))
        self.n_obstacle_objects = len(objects)
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        if objects:
            self.manager.registerObjects(objects)
        self.manager.setup()
        self.target_object = None
        self._target_item: tuple[np.ndarray, np.ndarray, np.ndarray, int] | None = None
        if target is not None:
            geom, tf = _object_geometry(target)
            self.target_object = self._register(geom, tf, Hit("target", target.name))
            self.target_manager = fcl.DynamicAABBTreeCollisionManager()
            self.target_manager.registerObjects([self.target_object])
            self.target_manager.setup()
            self._target_item = _object_bounds(target)
        self._target_name = "" if target is None else target.name
        # The items' bounds as arrays: centres (M, 3), rotations (M, 3, 3), half extents (M, 3), kinds (M,),
        # and the half extents of their world bounding boxes (M, 3).
        self._item_c = np.array([b[0] for b in bounds]).reshape(-1, 3)
        self._item_R = np.array([b[1] for b in bounds]).reshape(-1, 3, 3)
        self._item_h = np.array([b[2] for b in bounds]).reshape(-1, 3)
        self._item_kind = np.array([b[3] for b in bounds], dtype=np.int64)
        self._item_ext = np.matmul(np.abs(self._item_R), self._item_h[:, :, None])[:, :, 0]
        self._nohit_request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=False)
        self.support_object = None
        if support is not None:
            # fcl's halfspace is {x: n.x <= d}; the solid below the plane n.x + offset = 0 is n.x <= -offset.
            half = fcl.Halfspace(np.ascontiguousarray(support.normal), -float(support.offset_m))
            self.support_object = self._register(half, fcl.Transform(), Hit("support", "support plane"))
        self._request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=True)
        # Query boxes reused between calls, per half-extent triple: (geometry, object) pairs. fcl reports the
        # Python geometry of each contact, so the geometry identifies the query box.
        self._pool: dict[tuple[int, float, float, float], list[tuple[fcl.Box, fcl.CollisionObject]]] = {}
        self._capsules: dict[tuple[int, int], tuple[fcl.Capsule, fcl.CollisionObject]] = {}
        self._arm_cache: dict[int, list] = {}
        self._arm_managers: dict[tuple[int, ...], tuple] = {}

    def _register(self, geom, tf: fcl.Transform, hit: Hit) -> fcl.CollisionObject:
        self._labels[id(geom)] = hit
        return fcl.CollisionObject(geom, tf)

    def __repr__(self) -> str:
        return (
            f"CollisionScene({self.n_obstacle_objects} obstacle objects, {len(self.voxel_centres)} voxels, "
            f"target={'yes' if self.target is not None else 'no'}, "
            f"support={'yes' if self.support is not None else 'no'})"
        )

    # ------------------------------------------------------------------------------------------------------
    # single queries

    def _first_hit(self, obj: fcl.CollisionObject, manager) -> Hit | None:
        found: list[Hit] = []

        def callback(o1, o2, _):
            result = fcl.CollisionResult()
            if fcl.collide(o1, o2, self._request, result):
                c = result.contacts[0]
                found.append(self._labels.get(id(c.o1)) or self._labels.get(id(c.o2)) or Hit("object", "?"))
                return True
            return False

        manager.collide(obj, None, callback)
        return found[0] if found else None

    def collide_object(
        self, obj: fcl.CollisionObject, include_target: bool = True, include_support: bool = True
    ) -> Hit | None:
        """First thing an fcl object (in `base`) touches, or None."""
        hit = self._first_hit(obj, self.manager)
        if hit is None and include_target and self.target_object is not None:
            hit = self._first_hit(obj, self.target_manager)
        if hit is None and include_support and self.support_object is not None:
            if fcl.collide(obj, self.support_object, self._request, fcl.CollisionResult()):
                hit = Hit("support", "support plane")
        return hit

    # ------------------------------------------------------------------------------------------------------
    # batched oriented boxes (gripper hulls)

    def _pool_objects(
        self, key: tuple[int, float, float, float], n: int
    ) -> list[tuple[fcl.Box, fcl.CollisionObject]]:
        """n reusable query boxes for slot key = (slot index, half extents): two slots of equal size (the
        fingers) must not share objects."""
        half = key[1:]
        pool = self._pool.setdefault(key, [])
        while len(pool) < n:
            geom = fcl.Box(2.0 * half[0], 2.0 * half[1], 2.0 * half[2])
            pool.append((geom, fcl.CollisionObject(geom, fcl.Transform())))
        return pool[:n]

    def _resolve(
        self,
        qc: np.ndarray,
        qR: np.ndarray,
        qh: np.ndarray,
        owner: np.ndarray,
        hits: list,
        exact: np.ndarray | bool,
        query_object,
        label,
        items: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        objects: Sequence[tuple[fcl.CollisionObject, Hit, np.ndarray | None]],
        segments: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> int:
        """Fill `hits[owner[q]]` (where still None) with what query q touches among `items`.

        Args:
            qc, qR, qh: (Q, 3), (Q, 3, 3), (Q, 3) the queries' oriented boxes: the query itself where `exact`
                ((Q,) bool or one bool), else a box bounding it (a capsule, a cylinder).
            owner: (Q,) result slot of each query (a pose's or configuration's queries share one).
            query_object: q -> an fcl object placed at query q, for the narrowphase.
            label: (Hit of the scene item, q) -> the Hit to report.
            items: (centres, R, halves, kinds, world half extents) of the scene items; objects: their
                (fcl object, Hit, voxel centres or None).
            segments: (p0 (Q, 3), p1 (Q, 3), radius (Q,)) of queries that are capsules (radius NaN for the
                others): a voxel cube whose centre is within the radius of the segment is a certain hit, one
                farther than the radius + half the cube's diagonal certainly free; fcl decides the rest.

        Returns:
            the number of fcl narrowphase calls made.
        """
        free = np.array([h is None for h in hits], dtype=bool)
        alive = free[owner]
        exact_q = np.broadcast_to(np.asarray(exact, dtype=bool), alive.shape)
        ic, iR, ih, ikind, iext = items
        if not np.any(alive) or len(ic) == 0:
            return 0
        qidx = np.flatnonzero(alive)
        qext = np.matmul(np.abs(qR[qidx]), qh[qidx][:, :, None])[:, :, 0]
        qcs = qc[qidx]
        near = np.abs(qcs[:, None, 0] - ic[None, :, 0]) <= qext[:, None, 0] + iext[None, :, 0] + _SAT_EPS
        for ax in (1, 2):
            near &= (
                np.abs(qcs[:, None, ax] - ic[None, :, ax]) <= qext[:, None, ax] + iext[None, :, ax] + _SAT_EPS
            )
        rows_q, m = np.nonzero(near)
        if rows_q.size == 0:
            return 0
        q = qidx[rows_q]
        capsule = np.zeros(len(q), dtype=bool) if segments is None else np.isfinite(segments[2][q])
        # Boxes (and cylinders' bounds) against the items' oriented bounds by separating axes; capsules by
        # the segment's exact distance from the bounds (exact for box items, tighter than the capsule's
        # bounding box for the others).
        keep = np.ones(len(q), dtype=bool)
        nb = np.flatnonzero(~capsule)
        keep[nb] = obb_overlap(qc[q[nb]], qR[q[nb]], qh[q[nb]], ic[m[nb]], iR[m[nb]], ih[m[nb]])
        d_cap = np.full(len(q), np.inf)
        cp = np.flatnonzero(capsule)
        if cp.size and segments is not None:
            p0, p1, rad = (x[q[cp]] for x in segments)
            d_cap[cp] = _segment_box_distance(p0, p1, ic[m[cp]], iR[m[cp]], ih[m[cp]]) - rad
            keep[cp] = d_cap[cp] <= _DISTANCE_BAND_M
        q, m, capsule, d_cap = q[keep], m[keep], capsule[keep], d_cap[keep]
        decided = np.zeros(len(q), dtype=bool)  # the pair collides for certain
        narrow = np.ones(len(q), dtype=bool)  # the pair needs fcl
        box = (ikind[m] == _EXACT_BOX) & exact_q[q]
        decided |= box
        narrow &= ~box
        cb = np.flatnonzero(capsule & (ikind[m] == _EXACT_BOX))
        decided[cb] = d_cap[cb] <= -_DISTANCE_BAND_M
        narrow[cb] = np.abs(d_cap[cb]) <= _DISTANCE_BAND_M
        vox = np.flatnonzero(ikind[m] == _VOXELS)
        if vox.size:
            half = np.full(3, self.voxel_size_m / 2.0)
            narrow[vox] = False
            vb, vc = vox[~capsule[vox]], vox[capsule[vox]]
            if vb.size:
                # A box (or a cylinder's bounds) against each voxel cube of the block: world bounding boxes
                # first (cheap), the separating axes on the cubes inside them. Exact for boxes; a cylinder
                # with a cube inside its bounds goes to fcl.
                counts = np.array([len(objects[k][2]) for k in m[vb]])
                rows = np.repeat(vb, counts)
                cubes = np.concatenate([objects[k][2] for k in m[vb]])
                qe = np.matmul(np.abs(qR[q[rows]]), qh[q[rows]][:, :, None])[:, :, 0]
                d = np.abs(cubes - qc[q[rows]]) - qe - half
                inside = (d[:, 0] <= _SAT_EPS) & (d[:, 1] <= _SAT_EPS) & (d[:, 2] <= _SAT_EPS)
                rows, cubes = rows[inside], cubes[inside]
                touch = obb_overlap(qc[q[rows]], qR[q[rows]], qh[q[rows]], cubes, np.eye(3), half)
                any_touch = np.zeros(len(q), dtype=bool)
                any_touch[rows[touch]] = True
                decided[vb] = any_touch[vb] & exact_q[q[vb]]
                narrow[vb] = any_touch[vb] & ~exact_q[q[vb]]
            if vc.size and segments is not None:
                # A capsule near the block's bounds (above): each cube by the segment's distance.
                counts = np.array([len(objects[k][2]) for k in m[vc]], dtype=np.int64)
                rows = np.repeat(vc, counts)
                if rows.size:
                    cubes = np.concatenate([objects[k][2] for k in m[vc]])
                    p0, p1, rad = (x[q[rows]] for x in segments)
                    # The cube centre's distance settles most pairs (within the radius: touching; beyond the
                    # radius + half the cube's diagonal: apart); the exact distance only for the rest.
                    d = _points_segments_distance(cubes, p0, p1)
                    unsure = np.flatnonzero((d > rad) & (d <= rad + math.sqrt(3.0) * half[0]))
                    d[d > rad] = np.inf
                    eye = np.broadcast_to(np.eye(3), (len(unsure), 3, 3))
                    d[unsure] = _segment_box_distance(
                        p0[unsure], p1[unsure], cubes[unsure], eye, np.broadcast_to(half, (len(unsure), 3))
                    )
                    certain = np.zeros(len(q), dtype=bool)
                    certain[rows[d <= rad - _DISTANCE_BAND_M]] = True
                    close = np.zeros(len(q), dtype=bool)
                    close[rows[np.abs(d - rad) <= _DISTANCE_BAND_M]] = True
                    decided |= certain
                    narrow |= close & ~certain
        # Each owner reports the first item (in registration order: objects and fixtures before the observed
        # points) it touches: a pair fcl must decide is run only when its item comes before the owner's first
        # certain one.
        first_certain = np.full(len(hits), np.iinfo(np.int64).max)
        dk = np.flatnonzero(decided)
        np.minimum.at(first_certain, owner[q[dk]], m[dk])
        calls = 0
        todo = np.flatnonzero(narrow & ~decided & free[owner[q]])
        todo = todo[m[todo] < first_certain[owner[q[todo]]]]
        for k in todo[np.lexsort((m[todo], owner[q[todo]]))]:  # per owner, in item order
            o = owner[q[k]]
            if hits[o] is not None:
                continue
            calls += 1
            if fcl.collide(query_object(q[k]), objects[m[k]][0], self._nohit_request, fcl.CollisionResult()):
                hits[o] = label(objects[m[k]][1], q[k])
        for k in dk[np.lexsort((m[dk], owner[q[dk]]))]:
            o = owner[q[k]]
            if hits[o] is None and m[k] == first_certain[o]:
                hits[o] = label(objects[m[k]][1], q[k])
        return calls

    def _item_arrays(self, target: bool):
        if target:
            assert self._target_item is not None  # only called with a target
            c, R, h, kind = self._target_item
            ext = np.abs(R) @ h
            return (c[None], R[None], h[None], np.array([kind]), ext[None])
        return (self._item_c, self._item_R, self._item_h, self._item_kind, self._item_ext)

    def boxes_first_hits(
        self,
        R: np.ndarray,
        centres: np.ndarray,
        halves: Sequence[tuple[float, float, float]],
        include_target: np.ndarray | None = None,
    ) -> list[Hit | None]:
        """Which of N poses of a set of K boxes touch the scene (target optional per pose; support excluded).

        Box against box and against voxels is decided by the separating-axis test in numpy (exact); a box
        against a mesh by fcl, only where the box overlaps the mesh's oriented bounds.

        Args:
            R: (N, 3, 3) rotation of each pose (all K boxes share it).
            centres: (N, K, 3) box centres in `base` [m].
            halves: K half extents (x, y, z) [m] in the rotated frame.
            include_target: (N,) bool, check pose n against the target too; None: never.

        Returns:
            N entries: the first `Hit` of any of the pose's boxes (obstacles before the target), or None
            when it is free.
        """
        n, k = centres.shape[:2]
        hits: list[Hit | None] = [None] * n
        if n == 0:
            return hits
        H = np.asarray(halves, dtype=np.float64).reshape(k, 3)
        qc = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
        qR = np.repeat(np.asarray(R, dtype=np.float64), k, axis=0)
        qh = np.tile(H, (n, 1))
        owner = np.repeat(np.arange(n), k)
        boxes: dict[int, fcl.CollisionObject] = {}

        def query_object(q: int) -> fcl.CollisionObject:
            j = int(q % k)
            obj = boxes.get(j)
            if obj is None:
                obj = boxes[j] = fcl.CollisionObject(fcl.Box(*(2.0 * H[j])), fcl.Transform())
            obj.setTransform(_transform(qR[q], qc[q]))
            return obj

        def label(hit: Hit, _q: int) -> Hit:
            return hit

        items = self._item_arrays(False)
        self._resolve(qc, qR, qh, owner, hits, True, query_object, label, items, self._items)
        if self.target_object is not None and include_target is not None and np.any(include_target):
            allowed = np.repeat(np.asarray(include_target, dtype=bool), k)
            # Poses not checked against the target are masked by pretending they already hit (then reset).
            masked = [i for i in range(n) if hits[i] is None and not include_target[i]]
            for i in masked:
                hits[i] = _MASK
            sel = np.flatnonzero(allowed)
            self._resolve(
                qc[sel], qR[sel], qh[sel], owner[sel], hits, True,
                lambda q: query_object(int(sel[q])), label, self._item_arrays(True),
                [(self.target_object, Hit("target", self._target_name), None)],
            )  # fmt: skip
            for i in masked:
                hits[i] = None
        return hits

    # ------------------------------------------------------------------------------------------------------
    # the arm

    def _arm_capsules(self, robot) -> list[tuple[str, int, np.ndarray, float, float]]:
        """Per link capsule: (link name, link index, T_link_capsule (4, 4) centred, z along the axis, radius,
        length), computed once per robot model."""
        key = id(robot)
        cached = self._arm_cache.get(key)
        if cached is None:
            cached = []
            for i, link in enumerate(robot.description.links):
                for cap in link.capsules:
                    p0, p1 = np.asarray(cap.p0, dtype=np.float64), np.asarray(cap.p1, dtype=np.float64)
                    length = float(np.linalg.norm(p1 - p0))
                    T = np.eye(4)
                    T[:3, :3], T[:3, 3] = _z_to(p1 - p0, length), (p0 + p1) / 2.0
                    cached.append((link.name, i, T, float(cap.radius_m), length))
            self._arm_cache[key] = cached
        return cached

    def arm_objects(
        self, robot, q: np.ndarray
    ) -> list[tuple[str, fcl.CollisionObject, np.ndarray, float, float]]:
        """The arm's link capsules at q as fcl objects (created once, moved on each call): (link name, object,
        T_base_capsule, radius, length)."""
        frames = robot.link_frames(q)
        out = []
        for k, (name, i, T_local, radius, length) in enumerate(self._arm_capsules(robot)):
            entry = self._capsules.get((id(robot), k))
            if entry is None:
                geom = fcl.Capsule(radius, max(length, 1e-9))
                entry = (geom, fcl.CollisionObject(geom, fcl.Transform()))
                self._capsules[(id(robot), k)] = entry
                self._labels[id(geom)] = Hit("arm", name)
            T = frames[i] @ T_local
            entry[1].setTransform(_transform(T[:3, :3], T[:3, 3]))
            out.append((name, entry[1], T, radius, length))
        return out

    def arm_hit(
        self,
        robot,
        q: np.ndarray,
        include_target: bool = True,
        extra: Sequence[tuple[str, fcl.CollisionObject]] = (),
    ) -> Hit | None:
        """First thing the arm's link capsules at q (and `extra` named fcl objects moving with it: the
        gripper, a held object) touch, or None. The support is checked analytically against every capsule
        but the base links', and with fcl against `extra`."""
        capsules = self.arm_objects(robot, q)
        if self.support is not None:
            for name, _, T, radius, length in capsules:
                if name in _BASE_LINKS:
                    continue
                centre_h = float(self.support.height(T[:3, 3]))
                if centre_h - 0.5 * length * abs(float(T[:3, 2] @ self.support.normal)) < radius:
                    return Hit("support", f"support plane (arm link {name})")
        moving = [(name, obj) for name, obj, *_ in capsules] + list(extra)
        key = tuple(id(o) for _, o in moving)
        manager = self._arm_managers.get(key)
        if manager is None:
            manager = fcl.DynamicAABBTreeCollisionManager()
            manager.registerObjects([o for _, o in moving])
            manager.setup()
            self._arm_managers[key] = (manager, [o for _, o in moving])  # keep the objects alive with it
        else:
            manager = manager[0]
            manager.update()
        if isinstance(manager, tuple):
            manager = manager[0]
        found: list[Hit] = []

        def callback(o1, o2, _):
            result = fcl.CollisionResult()
            if fcl.collide(o1, o2, self._request, result):
                c = result.contacts[0]
                a, b = self._labels.get(id(c.o1)), self._labels.get(id(c.o2))
                # One side is the scene (labelled, not "arm"), the other an arm capsule (labelled "arm") or
                # a gripper part / held object (unlabelled).
                if a is not None and a.kind != "arm":
                    scene_hit, part = a, b
                else:
                    scene_hit, part = b, a
                if scene_hit is not None and scene_hit.kind != "arm":
                    where = f"arm link {part.name}" if part is not None else "gripper or held object"
                    found.append(Hit(scene_hit.kind, f"{scene_hit.name} ({where})"))
                    return True
            return False

        if self.n_obstacle_objects:
            manager.collide(self.manager, None, callback)
        if not found and include_target and self.target_object is not None:
            manager.collide(self.target_object, None, callback)
        if not found and self.support_object is not None:
            for _, obj in extra:
                if fcl.collide(obj, self.support_object, self._request, fcl.CollisionResult()):
                    return Hit("support", "support plane (gripper or held object)")
        return found[0] if found else None

    def arm_hits_batch(
        self,
        robot,
        Q: np.ndarray,
        include_target: bool = True,
        extra: Sequence[tuple[str, fcl.CollisionGeometry, np.ndarray, np.ndarray, str]] = (),
    ) -> list[Hit | None]:
        """`arm_hit` for N configurations at once: the first thing each configuration's link capsules (and
        `extra` parts moving with the flange) touch, or None.

        The link frames come from one batched forward kinematics; the support is checked analytically (every
        capsule but the base links', and the extra parts), the rest through the numpy broadphase (each
        capsule's bounding box against the scene items' oriented bounds, per voxel for observed points) and
        fcl's narrowphase for the pairs left.

        Args:
            robot: the `RobotModel`.
            Q: (N, 6) configurations [rad].
            include_target: check against the target too.
            extra: (name, fcl geometry (`fcl.Box` or `fcl.Cylinder`), T_flange_part (4, 4), half extents
                (3,) of the part's box or its cylinder's (r, r, h/2) [m], "box" or "cylinder").

        Returns:
            N entries, a `Hit` (its name says which link or part) or None.
        """
        Q = np.asarray(Q, dtype=np.float64).reshape(-1, 6)
        n = len(Q)
        hits: list[Hit | None] = [None] * n
        if n == 0:
            return hits
        caps = self._arm_capsules(robot)
        frames = link_frames_batch(robot.spec, Q)
        T = frames[:, [c[1] for c in caps]] @ np.stack([c[2] for c in caps])  # (N, C, 4, 4)
        radius = np.array([c[3] for c in caps])
        length = np.array([c[4] for c in caps])
        parts = [(name, geom, np.asarray(Tp, dtype=np.float64), np.asarray(h, dtype=np.float64), shape)
                 for name, geom, Tp, h, shape in extra]  # fmt: skip
        Tx = frames[:, 7][:, None] @ np.stack([p[2] for p in parts]) if parts else np.zeros((n, 0, 4, 4))
        if self.support is not None:
            nrm, off = self.support.normal, self.support.offset_m
            low = T[..., :3, 3] @ nrm + off - 0.5 * length * np.abs(T[..., :3, 2] @ nrm) - radius
            low[:, [c[0] in _BASE_LINKS for c in caps]] = np.inf
            for i in np.flatnonzero(np.any(low < 0.0, axis=1)):
                name = caps[int(np.argmax(low[i] < 0.0))][0]
                hits[i] = Hit("support", f"support plane (arm link {name})")
            for j, (name, _, _, half, shape) in enumerate(parts):
                dots = np.abs(np.einsum("nij,i->nj", Tx[:, j, :3, :3], nrm))  # (N, 3)
                if shape == "box":
                    reach = dots @ half
                else:
                    reach = dots[:, 2] * half[2] + half[0] * np.sqrt(np.maximum(0.0, 1.0 - dots[:, 2] ** 2))
                low_x = Tx[:, j, :3, 3] @ nrm + off - reach
                for i in np.flatnonzero(low_x < 0.0):
                    if hits[i] is None:
                        hits[i] = Hit("support", f"support plane ({name})")
        C, X = len(caps), len(parts)
        qc = np.concatenate([T[..., :3, 3], Tx[..., :3, 3]], axis=1).reshape(-1, 3)
        qR = np.concatenate([T[..., :3, :3], Tx[..., :3, :3]], axis=1).reshape(-1, 3, 3)
        cap_half = np.column_stack([radius, radius, 0.5 * length + radius])
        part_half = np.array([p[3] for p in parts]).reshape(-1, 3)
        qh = np.tile(np.vstack([cap_half, part_half]), (n, 1))
        exact = np.tile(np.array([False] * C + [p[4] == "box" for p in parts]), n)
        owner = np.repeat(np.arange(n), C + X)
        # Capsule segments (the extra parts are no capsules: NaN radius).
        axis_half = np.concatenate([0.5 * length, np.zeros(X)])[None, :, None] * np.concatenate(
            [T[..., :3, 2], Tx[..., :3, 2]], axis=1
        )
        centre = np.concatenate([T[..., :3, 3], Tx[..., :3, 3]], axis=1)
        segments = (
            (centre - axis_half).reshape(-1, 3),
            (centre + axis_half).reshape(-1, 3),
            np.tile(np.concatenate([radius, np.full(X, np.nan)]), n),
        )
        movers: dict[int, fcl.CollisionObject] = {}

        def query_object(q: int) -> fcl.CollisionObject:
            k = int(q % (C + X))
            obj = movers.get(k)
            if obj is None:
                if k < C:
                    obj = self.arm_object(robot, k)
                else:
                    obj = movers[k] = fcl.CollisionObject(parts[k - C][1], fcl.Transform())
            obj.setTransform(_transform(qR[q], qc[q]))
            return obj

        def label(hit: Hit, q: int) -> Hit:
            k = int(q % (C + X))
            where = f"arm link {caps[k][0]}" if k < C else parts[k - C][0]
            return Hit(hit.kind, f"{hit.name} ({where})")

        items = self._item_arrays(False)
        self._resolve(qc, qR, qh, owner, hits, exact, query_object, label, items, self._items, segments)
        if include_target and self.target_object is not None:
            self._resolve(
                qc, qR, qh, owner, hits, exact, query_object, label, self._item_arrays(True),
                [(self.target_object, Hit("target", self._target_name), None)], segments,
            )  # fmt: skip
        return hits

    def arm_object(self, robot, k: int) -> fcl.CollisionObject:
        """The fcl object of the robot's k-th link capsule (created once, moved by its users)."""
        entry = self._capsules.get((id(robot), k))
        if entry is None:
            _, _, _, radius, length = self._arm_capsules(robot)[k]
            geom = fcl.Capsule(radius, max(length, 1e-9))
            entry = (geom, fcl.CollisionObject(geom, fcl.Transform()))
            self._capsules[(id(robot), k)] = entry
            self._labels[id(geom)] = Hit("arm", self._arm_capsules(robot)[k][0])
        return entry[1]


def _points_segments_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(N,) distance [m] of each point P[i] (N, 3) from the segment p0[i] -> p1[i]."""
    d = p1 - p0
    L2 = np.einsum("ij,ij->i", d, d)
    s = np.einsum("ij,ij->i", P - p0, d) / np.maximum(L2, 1e-300)
    s = np.clip(np.where(L2 > 1e-18, s, 0.0), 0.0, 1.0)
    e = P - (p0 + s[:, None] * d)
    return np.sqrt(np.einsum("ij,ij->i", e, e))


def _segment_box_distance(
    p0: np.ndarray, p1: np.ndarray, c: np.ndarray, R: np.ndarray, h: np.ndarray
) -> np.ndarray:
    """(P,) distance [m] of segments p0 -> p1 (P, 3) from oriented boxes (centres c (P, 3), rotations R
    (P, 3, 3), half extents h (P, 3)); 0 where they meet.

    In the box frame the squared distance of p(t) = a + t v from the box is sum_i max(|a_i + t v_i| - h_i,
    0)^2: a quadratic in t between the (at most 6) values of t where a coordinate crosses a face plane. Its
    minimum on each of those pieces is closed form; the smallest over the pieces is the distance (exact)."""
    a = np.einsum("pi,pij->pj", p0 - c, R)  # segment ends in the box frames
    v = np.einsum("pi,pij->pj", p1 - c, R) - a
    with np.errstate(divide="ignore", invalid="ignore"):
        cross_t = np.concatenate([(h - a) / v, (-h - a) / v], axis=1)  # (P, 6)
    cross_t = np.where(np.isfinite(cross_t), np.clip(cross_t, 0.0, 1.0), 0.0)
    n = len(a)
    ts = np.sort(np.concatenate([np.zeros((n, 1)), np.ones((n, 1)), cross_t], axis=1), axis=1)  # (P, 8)
    lo, hi = ts[:, :-1], ts[:, 1:]  # (P, 7) pieces
    mid = 0.5 * (lo + hi)
    x = a[:, None, :] + mid[..., None] * v[:, None, :]  # (P, 7, 3)
    H = h[:, None, :]
    sign = np.where(x > H, 1.0, np.where(x < -H, -1.0, 0.0))  # which face plane is exceeded on the piece
    alpha = sign * a[:, None, :] - np.abs(sign) * H  # excess = alpha + beta t on the piece
    beta = sign * v[:, None, :]
    num = -np.sum(alpha * beta, axis=2)
    den = np.sum(beta * beta, axis=2)
    t = np.clip(np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), mid), lo, hi)
    e = np.maximum(np.abs(a[:, None, :] + t[..., None] * v[:, None, :]) - H, 0.0)
    return np.sqrt(np.min(np.sum(e * e, axis=2), axis=1))


def segment_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(N,) distances [m] of points (N, 3) from the segment p0 -> p1."""
    d = p1 - p0
    L2 = float(d @ d)
    s = np.zeros(len(P)) if L2 < 1e-18 else np.clip((P - p0) @ d / L2, 0.0, 1.0)
    return np.linalg.norm(P - (p0 + s[:, None] * d), axis=1)


def _z_to(axis: np.ndarray, length: float) -> np.ndarray:
    """A rotation whose z axis is along `axis` (identity for a zero axis)."""
    if length < 1e-12:
        return np.eye(3)
    z = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, cross(z, x), z], axis=1)
