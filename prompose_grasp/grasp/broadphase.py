"""The numpy broadphase of `CollisionScene`'s batched queries (hundreds of gripper poses or arm poses).

Each query is an oriented box (a gripper hull box, a gripper part) or a capsule (an arm link, with the box
bounding it); each scene item has an oriented bounding box and a kind. World bounding boxes are compared
first, then the separating-axis test between each query's box and each item's (exact for boxes), or for a
capsule the exact distance of its segment from the item's box. A box item is decided there; a block of voxel
cubes by the same tests against each cube of the block; only the pairs left (a box or capsule against a mesh,
a capsule touching a box or a cube within `DISTANCE_BAND_M`) go to fcl's narrowphase, one `fcl.collide`
each, skipping queries already known to collide.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple, TypeVar

import fcl
import numpy as np

from prompose_grasp.geometry.distance import obb_overlap, points_segments_distance, segment_box_distance
from prompose_grasp.geometry.tolerances import SAT_EPS
from prompose_grasp.grasp.types import ObjectModel

__all__ = [
    "DISTANCE_BAND_M",
    "EXACT_BOX",
    "NARROWPHASE",
    "VOXELS",
    "ItemBounds",
    "first_hits",
    "object_bounds",
]

#: Kinds of scene items of the numpy broadphase: a box decided exactly by the separating-axis test, a geometry
#: that needs fcl's narrowphase (mesh), a block of voxel cubes (decided per cube).
EXACT_BOX, NARROWPHASE, VOXELS = 0, 1, 2
#: A capsule whose segment is within this of its radius from a box [m] is left to fcl's narrowphase (the
#: numpy distance is exact to ~1e-10 m; fcl decides the touching cases).
DISTANCE_BAND_M = 1e-7


#: What a scene item reports when touched (the scene's `Hit`).
H = TypeVar("H")


class ItemBounds(NamedTuple):
    """The scene items' oriented bounds as arrays: centres (M, 3) [m], rotations (M, 3, 3), half extents
    (M, 3) [m], kinds (M,) (`EXACT_BOX`, `NARROWPHASE`, `VOXELS`), half extents of their world bounding boxes
    (M, 3) [m]."""

    centres: np.ndarray
    R: np.ndarray
    halves: np.ndarray
    kinds: np.ndarray
    ext: np.ndarray


def object_bounds(obj: ObjectModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(centre (3,), R (3, 3), half extents (3,), item kind): the object's box, or for a mesh the bounds of
    its vertices in the box frame (a mesh need not fit its estimated box)."""
    R = np.asarray(obj.pose.R, dtype=np.float64)
    if obj.mesh is None:
        return np.asarray(obj.pose.t, dtype=np.float64), R, np.asarray(obj.pose.size) / 2.0, EXACT_BOX
    local = (np.asarray(obj.mesh.vertices, dtype=np.float64) - obj.pose.t) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    kind = NARROWPHASE
    # A closed mesh inside its bounds with their volume is that box (a carton's prior): decided exactly.
    if len(local) <= 64 and getattr(obj.mesh, "is_watertight", False):
        box_volume = float(np.prod(hi - lo))
        if abs(abs(float(obj.mesh.volume)) - box_volume) <= 1e-6 * box_volume:
            kind = EXACT_BOX
    return obj.pose.t + R @ ((lo + hi) / 2.0), R, (hi - lo) / 2.0, kind


def first_hits(
    qc: np.ndarray,
    qR: np.ndarray,
    qh: np.ndarray,
    owner: np.ndarray,
    hits: list,
    exact: np.ndarray | bool,
    query_object: Callable[[int], fcl.CollisionObject],
    label: Callable[[H, int], H],
    items: ItemBounds,
    objects: Sequence[tuple[fcl.CollisionObject, H, np.ndarray | None]],
    segments: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    *,
    voxel_size_m: float,
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

        voxel_size_m: edge of the voxel cubes of the `VOXELS` items [m].

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
    near = np.abs(qcs[:, None, 0] - ic[None, :, 0]) <= qext[:, None, 0] + iext[None, :, 0] + SAT_EPS
    for ax in (1, 2):
        near &= np.abs(qcs[:, None, ax] - ic[None, :, ax]) <= qext[:, None, ax] + iext[None, :, ax] + SAT_EPS
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
        d_cap[cp] = segment_box_distance(p0, p1, ic[m[cp]], iR[m[cp]], ih[m[cp]]) - rad
        keep[cp] = d_cap[cp] <= DISTANCE_BAND_M
    q, m, capsule, d_cap = q[keep], m[keep], capsule[keep], d_cap[keep]
    decided = np.zeros(len(q), dtype=bool)  # the pair collides for certain
    narrow = np.ones(len(q), dtype=bool)  # the pair needs fcl
    box = (ikind[m] == EXACT_BOX) & exact_q[q]
    decided |= box
    narrow &= ~box
    cb = np.flatnonzero(capsule & (ikind[m] == EXACT_BOX))
    decided[cb] = d_cap[cb] <= -DISTANCE_BAND_M
    narrow[cb] = np.abs(d_cap[cb]) <= DISTANCE_BAND_M
    vox = np.flatnonzero(ikind[m] == VOXELS)
    if vox.size:
        half = np.full(3, voxel_size_m / 2.0)
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
            inside = (d[:, 0] <= SAT_EPS) & (d[:, 1] <= SAT_EPS) & (d[:, 2] <= SAT_EPS)
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
                d = points_segments_distance(cubes, p0, p1)
                unsure = np.flatnonzero((d > rad) & (d <= rad + math.sqrt(3.0) * half[0]))
                d[d > rad] = np.inf
                eye = np.broadcast_to(np.eye(3), (len(unsure), 3, 3))
                d[unsure] = segment_box_distance(
                    p0[unsure], p1[unsure], cubes[unsure], eye, np.broadcast_to(half, (len(unsure), 3))
                )
                certain = np.zeros(len(q), dtype=bool)
                certain[rows[d <= rad - DISTANCE_BAND_M]] = True
                close = np.zeros(len(q), dtype=bool)
                close[rows[np.abs(d - rad) <= DISTANCE_BAND_M]] = True
                decided |= certain
                narrow |= close & ~certain
    # Each owner reports the first item (in registration order: objects and fixtures before the observed
    # points) it touches: a pair fcl must decide is run only when its item comes before the owner's first
    # certain one.
    first_certain = np.full(len(hits), np.iinfo(np.int64).max)
    dk = np.flatnonzero(decided)
    np.minimum.at(first_certain, owner[q[dk]], m[dk])
    calls = 0
    request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=False)
    todo = np.flatnonzero(narrow & ~decided & free[owner[q]])
    todo = todo[m[todo] < first_certain[owner[q[todo]]]]
    for k in todo[np.lexsort((m[todo], owner[q[todo]]))]:  # per owner, in item order
        o = owner[q[k]]
        if hits[o] is not None:
            continue
        calls += 1
        if fcl.collide(query_object(q[k]), objects[m[k]][0], request, fcl.CollisionResult()):
            hits[o] = label(objects[m[k]][1], q[k])
    for k in dk[np.lexsort((m[dk], owner[q[dk]]))]:
        o = owner[q[k]]
        if hits[o] is None and m[k] == first_certain[o]:
            hits[o] = label(objects[m[k]][1], q[k])
    return calls
