"""The collision scene on python-fcl: support plane, other objects, observed points, the target, the arm.

One `CollisionScene` holds, in `base`:

- the support plane (an `fcl.Halfspace`, in its own manager: the arm's base links stand on it, so it is
  checked only against the links that must clear it, and against grippers analytically in the planner);
- every other object as its estimated box (`fcl.Box`) or scaled mesh (`fcl.BVHModel`), fixtures likewise;
- the observed point cloud without the target's own points and the support's, as voxel cubes, one
  `fcl.BVHModel` per 10 cm block (`voxels`);
- the target itself (separately: grasps must touch it, so only some checks include it).

Single queries (`collide_object`, `arm_hit`) go through fcl's `DynamicAABBTreeCollisionManager`
(broadphase). Batched queries (hundreds of gripper poses, or arm configurations, at once: `boxes_first_hits`,
`arm_hits_batch`) run their broadphase in numpy instead (`broadphase.first_hits`: separating axes and exact
segment-box distances, fcl's narrowphase only for the pairs those leave open). Every query reports *what*
was hit: the kind ("object", "fixture", "points", "target", "support") and the obstacle's name.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.distance import rotation_z_along, segment_distance
from prompose_grasp.grasp.batch_ik import link_frames_batch
from prompose_grasp.grasp.broadphase import VOXELS, ItemBounds, first_hits, object_bounds
from prompose_grasp.grasp.types import ObjectModel, Plane
from prompose_grasp.grasp.voxels import voxel_blocks, voxelize_points
from prompose_grasp.robot.urdf import BASE_LINKS

__all__ = ["CollisionScene", "Hit"]

log = logging.getLogger(__name__)


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
            bounds.append(object_bounds(obs))
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
                # One mesh per block of voxels (`voxel_blocks`), each an item of the broadphase.
                for C, V, F in voxel_blocks(self.voxel_centres, self.voxel_size_m):
                    objects.append(
                        self._register(_bvh(V, F), fcl.Transform(), Hit("points", "observed points"))
                    )
                    lo, hi = C.min(axis=0) - voxel_size_m / 2.0, C.max(axis=0) + voxel_size_m / 2.0
                    self._items.append((objects[-1], Hit("points", "observed points"), C))
                    bounds.append(((lo + hi) / 2.0, np.eye(3), (hi - lo) / 2.0, VOXELS))
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
            self._target_item = object_bounds(target)
        self._target_name = "" if target is None else target.name
        # The items' bounds as arrays: centres (M, 3), rotations (M, 3, 3), half extents (M, 3), kinds (M,),
        # and the half extents of their world bounding boxes (M, 3).
        self._item_c = np.array([b[0] for b in bounds]).reshape(-1, 3)
        self._item_R = np.array([b[1] for b in bounds]).reshape(-1, 3, 3)
        self._item_h = np.array([b[2] for b in bounds]).reshape(-1, 3)
        self._item_kind = np.array([b[3] for b in bounds], dtype=np.int64)
        self._item_ext = np.matmul(np.abs(self._item_R), self._item_h[:, :, None])[:, :, 0]
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

    def _item_arrays(self, target: bool) -> ItemBounds:
        if target:
            assert self._target_item is not None  # only called with a target
            c, R, h, kind = self._target_item
            ext = np.abs(R) @ h
            return ItemBounds(c[None], R[None], h[None], np.array([kind]), ext[None])
        return ItemBounds(self._item_c, self._item_R, self._item_h, self._item_kind, self._item_ext)

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
        first_hits(
            qc, qR, qh, owner, hits, True, query_object, label, items, self._items,
            voxel_size_m=self.voxel_size_m,
        )  # fmt: skip
        if self.target_object is not None and include_target is not None and np.any(include_target):
            allowed = np.repeat(np.asarray(include_target, dtype=bool), k)
            # Poses not checked against the target are masked by pretending they already hit (then reset).
            masked = [i for i in range(n) if hits[i] is None and not include_target[i]]
            for i in masked:
                hits[i] = _MASK
            sel = np.flatnonzero(allowed)
            first_hits(
                qc[sel], qR[sel], qh[sel], owner[sel], hits, True,
                lambda q: query_object(int(sel[q])), label, self._item_arrays(True),
                [(self.target_object, Hit("target", self._target_name), None)],
                voxel_size_m=self.voxel_size_m,
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
                    T[:3, :3], T[:3, 3] = rotation_z_along(p1 - p0, length), (p0 + p1) / 2.0
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
                if name in BASE_LINKS:
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
            low[:, [c[0] in BASE_LINKS for c in caps]] = np.inf
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
        first_hits(
            qc, qR, qh, owner, hits, exact, query_object, label, items, self._items, segments,
            voxel_size_m=self.voxel_size_m,
        )  # fmt: skip
        if include_target and self.target_object is not None:
            first_hits(
                qc, qR, qh, owner, hits, exact, query_object, label, self._item_arrays(True),
                [(self.target_object, Hit("target", self._target_name), None)], segments,
                voxel_size_m=self.voxel_size_m,
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
