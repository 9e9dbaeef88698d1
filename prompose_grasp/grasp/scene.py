"""The collision scene on python-fcl: support plane, other objects, observed points, the target, the arm.

One `CollisionScene` holds, in `base`:

- the support plane (an `fcl.Halfspace`, in its own manager: the arm's base links stand on it, so it is
  checked only against the links that must clear it, and against grippers analytically in the planner);
- every other object as its estimated box (`fcl.Box`) or scaled mesh (`fcl.BVHModel`), fixtures likewise;
- the observed point cloud without the target's own points and the support's, as voxel boxes: every occupied
  voxel becomes a cube, and all cubes together one `fcl.BVHModel` (12 triangles a cube; a cube overlapped by a
  gripper box is found because one of its triangles intersects or lies in the box);
- the target itself (separately: grasps must touch it, so only some checks include it).

Queries go through fcl's `DynamicAABBTreeCollisionManager` (broadphase) and report *what* was hit: the kind
("object", "fixture", "points", "target", "support") and the obstacle's name. Batched queries (many gripper
poses at once) register all the query boxes in one manager and collide it with the scene manager, so the
broadphase runs once in C++ and Python sees only the pairs whose bounding boxes overlap.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp.synthesis import cross
from prompose_grasp.grasp.types import ObjectModel, Plane

__all__ = ["CollisionScene", "Hit", "voxelize_points"]

log = logging.getLogger(__name__)

#: Edge of the blocks the voxel meshes are split into [m] (about a swept gripper box: fewer pairs).
_VOXEL_BLOCK_M = 0.25
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
        objects = []
        for obs in obstacles:
            if not isinstance(obs, ObjectModel):
                raise InvalidInputError(f"obstacles must be ObjectModel values, got {type(obs).__name__}")
            if support is not None and float(np.max(support.height(obs.pose.corners()))) <= 0.0:
                continue  # entirely below the support plane: the plane already stands for it
            geom, tf = _object_geometry(obs)
            objects.append(self._register(geom, tf, Hit(obs.kind, obs.name)))
        self.voxel_centres = np.zeros((0, 3))
        self.voxel_size_m = float(voxel_size_m)
        if points_base is not None:
            P = np.asarray(points_base, dtype=np.float64)
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
                P = P[_segment_distance(P, np.asarray(p0), np.asarray(p1)) > radius + robot_margin_m]
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
        self.n_obstacle_objects = len(objects)
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        if objects:
            self.manager.registerObjects(objects)
        self.manager.setup()
        self.target_object = None
        if target is not None:
            geom, tf = _object_geometry(target)
            self.target_object = self._register(geom, tf, Hit("target", target.name))
            self.target_manager = fcl.DynamicAABBTreeCollisionManager()
            self.target_manager.registerObjects([self.target_object])
            self.target_manager.setup()
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

    def boxes_first_hits(
        self,
        R: np.ndarray,
        centres: np.ndarray,
        halves: Sequence[tuple[float, float, float]],
        include_target: np.ndarray | None = None,
    ) -> list[Hit | None]:
        """Which of N poses of a set of K boxes touch the scene (target optional per pose; support excluded).

        Args:
            R: (N, 3, 3) rotation of each pose (all K boxes share it).
            centres: (N, K, 3) box centres in `base` [m].
            halves: K half extents (x, y, z) [m] in the rotated frame.
            include_target: (N,) bool, check pose n against the target too; None: never.

        Returns:
            N entries: the first `Hit` of any of the pose's boxes, or None when it is free.
        """
        n, _k = centres.shape[:2]
        hits: list[Hit | None] = [None] * n
        if n == 0:
            return hits
        geom_owner: dict[int, int] = {}  # id(geometry) -> pose index
        # Translation bytes -> pose index: lets the callback skip pairs of poses already known to collide
        # without a narrowphase call. Only a shortcut: the verdict always comes from fcl's contact geometry.
        # Several boxes may share a centre (a finger of a pose and the other finger of its flipped twin).
        centre_owner: dict[bytes, list[int]] = {}
        objects = []
        for j, half in enumerate(halves):
            pool = self._pool_objects((j, float(half[0]), float(half[1]), float(half[2])), n)
            for i, (geom, obj) in enumerate(pool):
                c = np.ascontiguousarray(centres[i, j], dtype=np.float64)
                obj.setTransform(_transform(R[i], c))
                geom_owner[id(geom)] = i
                centre_owner.setdefault(c.tobytes(), []).append(i)
                objects.append(obj)
        query = fcl.DynamicAABBTreeCollisionManager()
        query.registerObjects(objects)
        query.setup()

        def callback_for(allowed: np.ndarray | None):
            def callback(o1, o2, _):
                for o in (o1, o2):
                    owners = centre_owner.get(o.getTranslation().tobytes())
                    if owners is not None and all(hits[i] is not None for i in owners):
                        return False
                result = fcl.CollisionResult()
                if fcl.collide(o1, o2, self._request, result):
                    c = result.contacts[0]
                    a, b = id(c.o1), id(c.o2)
                    i = geom_owner.get(a, geom_owner.get(b))
                    label = self._labels.get(b) or self._labels.get(a)
                    if i is not None and hits[i] is None and label is not None:
                        if allowed is None or allowed[i]:
                            hits[i] = label
                return False

            return callback

        if self.n_obstacle_objects:
            query.collide(self.manager, None, callback_for(None))
        if self.target_object is not None and include_target is not None and np.any(include_target):
            query.collide(self.target_object, None, callback_for(np.asarray(include_target, dtype=bool)))
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


def _segment_distance(P: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
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
