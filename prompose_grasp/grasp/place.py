"""Place planning: where to put a held object on a surface, into a bin, or onto a pallet (palletising).

The object keeps its attitude relative to gravity (it is put down on the face it stood on) and may turn about
the surface normal in quarter turns. Its estimated size gives its footprint and the height of its centre
above the surface (plus `drop_clearance_m`: the gripper lets go just above the surface). The tcp pose follows
from the grasp: `T_base_tcp = T_base_obj_place @ T_obj_tcp`, with `T_obj_tcp` fixed while the object is held.

- surface / bin: a grid of positions where the whole footprint is inside the surface (a bin's inner floor,
  less `wall_margin_m` from its walls), nearest the preferred point (the centre, or `near_xy_m`) first;
- pallet: a `PalletPattern` (rows x cols x layers, gap between cartons; column-stacked, or interlocked with
  odd layers turned a quarter turn) sized from the object's estimated footprint and height; slots are filled
  layer by layer, row by row; a slot is taken when an obstacle box's centre lies in it, and a slot above
  layer 0 needs every slot it rests on taken.

Each candidate is checked: the object's box (shrunk by `contact_margin_m`) and the gripper's hull boxes swept
from the pre-place pose against the obstacles (python-fcl, same scene as grasping), closed-form IK within the
limits, and the arm's capsules at that solution. The first that passes is returned (with all passing ones
ranked when asked).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, NoFeasiblePlace
from prompose_grasp.geometry.se3 import as_transform, invert_T, make_T
from prompose_grasp.grasp.batch_ik import branch_order, fk_reaches, ik_nearest_batch
from prompose_grasp.grasp.grippers import ParallelJawGeometry, SuctionCupGeometry, as_gripper
from prompose_grasp.grasp.planner import gripper_hulls
from prompose_grasp.grasp.scene import CollisionScene
from prompose_grasp.grasp.types import Grasp, ObjectModel
from prompose_grasp.robot.model import RobotModel

log = logging.getLogger(__name__)

__all__ = [
    "PLACE_KINDS",
    "PalletPattern",
    "PalletSlot",
    "PlaceConfig",
    "PlacePose",
    "PlaceTarget",
    "footprint",
    "pallet_layout",
    "pallet_slots",
    "plan_place",
]

#: The kinds of place target.
PLACE_KINDS = ("surface", "bin", "pallet")


@dataclass(frozen=True)
class PalletPattern:
    """A carton stacking pattern: `rows` (along the pallet's y) x `cols` (along x) x `layers`, with `gap_m`
    between neighbouring cartons [m].

    Column stack (`interlock=False`): every layer the same, each carton on the one below. Interlocked
    (`interlock=True`): odd layers are turned a quarter turn, the cartons rotated 90 deg about the normal and
    the grid transposed (`rows` columns along x, `cols` rows along y), so the seams of neighbouring layers
    cross and each upper carton bridges the ones below (the pattern must fit the deck both ways)."""

    rows: int = 3
    cols: int = 3
    layers: int = 2
    gap_m: float = 0.01
    interlock: bool = False

    def __post_init__(self) -> None:
        if min(self.rows, self.cols, self.layers) < 1 or not (math.isfinite(self.gap_m) and self.gap_m >= 0):
            raise InvalidInputError(f"PalletPattern needs rows, cols, layers >= 1 and gap_m >= 0, got {self}")


@dataclass(frozen=True, eq=False)
class PlaceTarget:
    """Where to place: a flat surface, a bin's floor, or a pallet's deck.

    Attributes:
        kind: "surface", "bin" or "pallet".
        T_base_surface: (4, 4) frame at the centre of the standing surface in `base`, z up (normal) [m].
        half_extents_xy_m: (2,) half size of the usable surface along its x and y [m].
        wall_height_m: height of a bin's walls above its floor [m] (0 for the others).
        pattern: the stacking pattern of a pallet (default `PalletPattern()`).
    """

    kind: str
    T_base_surface: np.ndarray
    half_extents_xy_m: np.ndarray
    wall_height_m: float = 0.0
    pattern: PalletPattern | None = None

    def __post_init__(self) -> None:
        if self.kind not in PLACE_KINDS:
            raise InvalidInputError(
                f"PlaceTarget.kind must be one of {', '.join(PLACE_KINDS)}, got {self.kind!r}"
            )
        object.__setattr__(self, "T_base_surface", as_transform(self.T_base_surface, "T_base_surface"))
        half = np.asarray(self.half_extents_xy_m, dtype=np.float64)
        if half.shape != (2,) or not np.all(np.isfinite(half)) or np.any(half <= 0):
            raise InvalidInputError(
                f"half_extents_xy_m must be (2,) finite > 0 [m], got {self.half_extents_xy_m}"
            )
        object.__setattr__(self, "half_extents_xy_m", half)
        if self.kind == "pallet" and self.pattern is None:
            object.__setattr__(self, "pattern", PalletPattern())


@dataclass(frozen=True)
class PlaceConfig:
    """Settings of place planning.

    Attributes:
        approach_m: the pre-place pose is this far above the place pose along the surface normal [m].
        retreat_m: after release the tcp backs off this far along -approach (tcp -z) [m].
        drop_clearance_m: the object is released this far above the surface [m].
        contact_margin_m: the object's box is shrunk by this for collision checks (it touches its
            neighbours' estimates within the estimation error) [m].
        wall_margin_m: distance kept from a bin's walls [m].
        grid_step_m: spacing of surface / bin positions [m].
        near_xy_m: preferred position in the surface frame (x, y) [m], or None for the centre.
        max_candidates: place candidates examined, nearest the preferred point first.
    """

    approach_m: float = 0.10
    retreat_m: float = 0.10
    drop_clearance_m: float = 0.005
    contact_margin_m: float = 0.003
    wall_margin_m: float = 0.01
    grid_step_m: float = 0.04
    near_xy_m: tuple[float, float] | None = None
    max_candidates: int = 200


@dataclass(frozen=True, eq=False)
class PlacePose:
    """A collision-checked place.

    Attributes:
        T_base_obj: (4, 4) object (box centre) pose at release [m].
        T_base_tcp: (4, 4) tcp at release; T_base_preplace: (4, 4) tcp `approach_m` above it;
        T_base_retreat: (4, 4) tcp after release, backed off along the approach.
        q: (6,) arm configuration at release [rad].
        slot: (row, col, layer) on a pallet, else None.
        reason: in words.
    """

    T_base_obj: np.ndarray
    T_base_tcp: np.ndarray
    T_base_preplace: np.ndarray
    T_base_retreat: np.ndarray
    q: np.ndarray
    slot: tuple[int, int, int] | None
    reason: str


def footprint(R_surface_obj: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, float]:
    """(half extents along surface x, y (2,), half height along the normal) of a box of `size` (3,) [m]
    turned by `R_surface_obj` (3, 3) in the surface's frame: what it covers of the surface."""
    half = np.abs(R_surface_obj) @ (size / 2.0)
    return half[:2], float(half[2])


def _rz(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class PalletSlot:
    """One carton place of a pallet pattern, in the surface frame.

    Attributes:
        index: (row, col, layer) in the layer's own grid.
        centre_m: (3,) centre of the carton box [m] (on the deck or on the layer below).
        yaw_rad: the carton's turn about the surface normal from its attitude at the grasp [rad].
        half_xy_m: (2,) half footprint along the surface x, y at that yaw [m].
    """

    index: tuple[int, int, int]
    centre_m: np.ndarray
    yaw_rad: float
    half_xy_m: np.ndarray


def pallet_layout(target: PlaceTarget, footprint_half_xy: np.ndarray, half_height: float) -> list[PalletSlot]:
    """The slots of the pallet's pattern for a carton of half footprint `footprint_half_xy` (2,) (surface x,
    y, unturned) and half height [m], in filling order: layer by layer, row by row.

    Raises `InvalidInputError` when a layer of the pattern does not fit on the deck."""
    p = target.pattern or PalletPattern()
    out = []
    for layer in range(p.layers):
        turned = p.interlock and layer % 2 == 1
        half = (
            np.asarray(footprint_half_xy, dtype=np.float64)[::-1] if turned else np.asarray(footprint_half_xy)
        )
        n_rows, n_cols = (p.cols, p.rows) if turned else (p.rows, p.cols)
        pitch = 2.0 * half + p.gap_m
        total = np.array([n_cols, n_rows]) * pitch - p.gap_m
        if np.any(total / 2.0 > target.half_extents_xy_m + 1e-9):
            raise InvalidInputError(
                f"pallet pattern {n_rows} x {n_cols} of {2 * half.round(3)} m cartons "
                f"({total.round(3)} m) does not fit the deck ({2 * target.half_extents_xy_m.round(3)} m)"
            )
        for row in range(n_rows):
            for col in range(n_cols):
                x = -total[0] / 2.0 + half[0] + col * pitch[0]
                y = -total[1] / 2.0 + half[1] + row * pitch[1]
                z = half_height + layer * 2.0 * half_height
                out.append(
                    PalletSlot((row, col, layer), np.array([x, y, z]), 0.5 * math.pi * turned, half.copy())
                )
    return out


def pallet_slots(
    target: PlaceTarget, footprint_half_xy: np.ndarray, half_height: float
) -> list[tuple[tuple[int, int, int], np.ndarray]]:
    """Slot centres of the pallet pattern, in the surface frame, in filling order (`pallet_layout` without the
    turns).

    Returns:
        [((row, col, layer), (3,) centre of the carton box in the surface frame [m])], layer by layer, row by
        row. Raises `InvalidInputError` when the pattern does not fit on the deck.
    """
    return [(s.index, s.centre_m) for s in pallet_layout(target, footprint_half_xy, half_height)]


def _supports(slot: PalletSlot, below: Sequence[PalletSlot]) -> list[PalletSlot]:
    """The slots of the layer below whose footprint overlaps this slot's by more than 1 cm each way."""
    d = [np.abs(b.centre_m[:2] - slot.centre_m[:2]) for b in below]
    return [b for b, dd in zip(below, d) if np.all(dd < slot.half_xy_m + b.half_xy_m - 0.01)]


def plan_place(
    obj: ObjectModel,
    grasp: Grasp,
    target: PlaceTarget,
    robot: RobotModel,
    gripper: ParallelJawGeometry | SuctionCupGeometry | str = "parallel_jaw",
    obstacles: Sequence[ObjectModel] = (),
    points_base: ArrayLike | None = None,
    q_seed: ArrayLike | None = None,
    config: PlaceConfig | None = None,
    scene: CollisionScene | None = None,
) -> PlacePose:
    """The best collision-free, reachable place pose for `obj` held by `grasp` (see the module docstring).

    Args:
        obj: the held object as estimated at the grasp (`ObjectModel` in `base`).
        grasp: the grasp holding it (its `T_base_tcp` fixes T_obj_tcp).
        target: surface, bin or pallet.
        robot, gripper: as for `plan_grasps`.
        obstacles: everything else (not the held object), in `base`; placed cartons included.
        points_base: (N, 3) observed points in `base` [m], or None.
        q_seed: (6,) configuration to stay near [rad] (the grasp's by default).
        config: `PlaceConfig`.
        scene: a prebuilt `CollisionScene` without the held object.

    Raises:
        NoFeasiblePlace: no candidate passed (with counts per reason); on a pallet whose pattern of cartons
            this size does not fit the deck, with the reason "pattern_too_large" (the layout's message is
            the exception's `__cause__`).
    """
    cfg = config or PlaceConfig()
    grip = as_gripper(gripper)
    seed = (
        (grasp.q if grasp.q is not None else np.zeros(6))
        if q_seed is None
        else robot.check_q(q_seed, "q_seed")
    )
    if scene is None:
        scene = CollisionScene(obstacles, None, points_base, None)
    T_surf = target.T_base_surface
    n_up = T_surf[:3, 2]
    T_obj_tcp = invert_T(obj.pose.to_matrix()) @ grasp.T_base_tcp
    R_surf_obj = T_surf[:3, :3].T @ obj.pose.R  # the object's attitude seen from the surface frame
    size = obj.pose.size

    candidates: list[tuple[tuple[int, int, int] | None, np.ndarray, float]] = []  # (slot, centre_surf, yaw)
    if target.kind == "pallet":
        half_xy, half_h = footprint(R_surf_obj, size)
        try:
            layout = pallet_layout(target, half_xy, half_h)
        except InvalidInputError as exc:  # the pattern of cartons this size is larger than the deck
            log.info("no place on the pallet: %s", exc)
            raise NoFeasiblePlace({"pattern_too_large": 1}, 0) from exc
        taken = _taken_slots(target, obstacles, layout)
        for slot in layout:
            layer = slot.index[2]
            if slot.index in taken:
                continue
            # A slot above the deck needs every slot it rests on taken (one below in a column stack, the
            # two or more it bridges when interlocked).
            below = [b for b in layout if b.index[2] == layer - 1]
            if layer > 0 and not all(b.index in taken for b in _supports(slot, below)):
                continue
            centre = slot.centre_m + np.array([0.0, 0.0, cfg.drop_clearance_m])
            candidates.append((slot.index, centre, slot.yaw_rad))
    else:
        margin = cfg.wall_margin_m if target.kind == "bin" else 0.0
        near = np.zeros(2) if cfg.near_xy_m is None else np.asarray(cfg.near_xy_m, dtype=np.float64)
        for yaw in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi):
            half_xy, half_h = footprint(_rz(yaw) @ R_surf_obj, size)
            room = target.half_extents_xy_m - half_xy - margin
            if np.any(room < 0):
                continue
            xs = np.arange(-room[0], room[0] + 1e-9, cfg.grid_step_m) if room[0] > 0 else np.zeros(1)
            ys = np.arange(-room[1], room[1] + 1e-9, cfg.grid_step_m) if room[1] > 0 else np.zeros(1)
            X, Y = np.meshgrid(xs - xs.mean(), ys - ys.mean(), indexing="ij")
            for x, y in zip(X.ravel(), Y.ravel()):
                candidates.append((None, np.array([x, y, half_h + cfg.drop_clearance_m]), yaw))
        candidates.sort(key=lambda c: (float(np.linalg.norm(c[1][:2] - near)), c[2]))
    candidates = candidates[: cfg.max_candidates]
    if not candidates:
        raise NoFeasiblePlace({"no_room": 1}, 0)

    rejected: Counter[str] = Counter()
    T_tcp_flange = invert_T(grip.T_flange_tcp)
    lower, upper = robot.joint_limits
    halves, centres_tcp = gripper_hulls(grip, np.array([grasp.opening_m]), cfg.approach_m)
    shrink = np.maximum(size / 2.0 - cfg.contact_margin_m, 1e-4)
    for place_slot, centre, yaw in candidates:
        T_obj = T_surf @ make_T(_rz(yaw) @ R_surf_obj, centre)
        T_tcp = T_obj @ T_obj_tcp
        T_pre = T_tcp.copy()
        T_pre[:3, 3] += cfg.approach_m * n_up
        T_ret = T_tcp.copy()
        T_ret[:3, 3] -= cfg.retreat_m * T_tcp[:3, 2]
        # The held object's box at the place pose, and the gripper's swept hulls.
        R = np.stack([T_obj[:3, :3], T_tcp[:3, :3]])
        obj_hit = scene.boxes_first_hits(R[:1], T_obj[None, None, :3, 3], [tuple(shrink)])[0]
        if obj_hit is not None:
            rejected[f"object_{obj_hit.reason}"] += 1
            continue
        c = (T_tcp[:3, :3] @ centres_tcp[0].T).T + T_tcp[:3, 3]
        grip_hit = scene.boxes_first_hits(R[1:], c[None], halves)[0]
        if grip_hit is not None:
            rejected[grip_hit.reason] += 1
            continue
        Ts = np.stack([T_tcp, T_pre, T_ret]) @ T_tcp_flange
        q, ok, branches = ik_nearest_batch(robot.spec, Ts[:1], seed, lower, upper)
        if not ok[0]:
            rejected["ik"] += 1
            continue
        # Every in-limit branch, nearest the seed first, until one has a free arm and reaches the approach
        # and retreat poses on the same branch.
        why, q_ok = "arm_collision", None
        for qb in branch_order(q[0], branches[0]):
            if not fk_reaches(robot.fk(qb), Ts[0]):
                continue
            q_near, ok_near, _ = ik_nearest_batch(robot.spec, Ts[1:], np.vstack([qb, qb]), lower, upper)
            if not np.all(ok_near) or np.max(np.linalg.norm(q_near - qb, axis=1)) > 1.0:
                why = "ik_approach"
                continue
            if scene.arm_hit(robot, qb) is None:
                q_ok = qb
                break
            why = "arm_collision"
        if q_ok is None:
            rejected[why] += 1
            continue
        where = (
            f"slot row {place_slot[0]} col {place_slot[1]} layer {place_slot[2]}"
            if place_slot
            else f"at {centre[:2].round(3)} m"
        )
        return PlacePose(
            T_base_obj=T_obj,
            T_base_tcp=T_tcp,
            T_base_preplace=T_pre,
            T_base_retreat=T_ret,
            q=q_ok,
            slot=place_slot,
            reason=f"{target.kind}: {where} of the surface frame, yaw {math.degrees(yaw):.0f} deg",
        )
    raise NoFeasiblePlace(dict(rejected), len(candidates))


def _taken_slots(
    target: PlaceTarget, obstacles: Sequence[ObjectModel], layout: Sequence[PalletSlot]
) -> set[tuple[int, int, int]]:
    """Slots whose volume holds an obstacle box's centre."""
    taken = set()
    T_surf_base = invert_T(target.T_base_surface)
    centres = [T_surf_base[:3, :3] @ o.pose.t + T_surf_base[:3, 3] for o in obstacles]
    for slot in layout:
        half_h = slot.centre_m[2] / (2 * slot.index[2] + 1)
        for c in centres:
            if (
                np.all(np.abs(c[:2] - slot.centre_m[:2]) <= slot.half_xy_m)
                and abs(c[2] - slot.centre_m[2]) <= half_h
            ):
                taken.add(slot.index)
                break
    return taken
