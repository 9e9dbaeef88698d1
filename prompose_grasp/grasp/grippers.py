"""Gripper geometry: the one source of truth for the parallel-jaw gripper and the suction cup.

The MuJoCo stand-in (`sim.grippers`) builds its bodies and geoms from these dataclasses, and the grasp layer
builds its collision geometry from them, so planning and simulation see the same shapes.

Frames. The gripper is mounted on the UR flange (tool0, z out of the flange); its `tcp` has the flange's
orientation and sits on the flange z axis at `T_flange_tcp`:

- Parallel jaw: tcp = the centre between the two pad faces, `T_flange_tcp` = translation (0, 0, 0.145) m.
  The fingers close along tcp +-y, symmetrically about the tcp; the approach direction is tcp +z (from the
  palm towards the fingertips). `opening_m` is the distance between the two pad faces (0 .. 0.085 m).
- Suction: tcp = the centre of the cup face, `T_flange_tcp` = translation (0, 0, 0.100) m; tcp +z points out
  of the face into the object (the approach direction).

`parts(opening_m)` lists the collision primitives (boxes and cylinders) in the tcp frame, exactly those of the
sim; `hull_boxes(opening_m)` groups them into a few tcp-aligned boxes that contain them (palm, each finger),
which the planner sweeps along the approach.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import make_T

__all__ = [
    "GRAVITY_M_S2",
    "GRIPPER_KINDS",
    "GRIPPER_TCP",
    "GripperGeometry",
    "GripperPart",
    "ParallelJawGeometry",
    "SuctionCupGeometry",
    "as_gripper",
    "get_gripper",
]

#: Standard gravity [m/s^2] (payload limits).
GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class GripperPart:
    """One collision primitive of a gripper, in the tcp frame.

    Attributes:
        name: part name, the sim geom's name where there is one ("pad_left", "gripper_housing", ...).
        shape: "box" or "cylinder" (cylinder axis along the part's z).
        size_m: (3,) box half extents (x, y, z), or (radius, half height, 0) for a cylinder [m].
        T_tcp_part: (4, 4) pose of the part's centre in the tcp frame.
        group: "palm" or "finger_left" / "finger_right" / "cup": which hull box contains it.
    """

    name: str
    shape: str
    size_m: tuple[float, float, float]
    T_tcp_part: np.ndarray = field(repr=False)
    group: str

    def aabb_tcp(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (3,) each: the part's axis-aligned bounds in the tcp frame [m] (parts are tcp-aligned)."""
        c = self.T_tcp_part[:3, 3]
        half = (
            np.array(self.size_m)
            if self.shape == "box"
            else np.array([self.size_m[0], self.size_m[0], self.size_m[1]])
        )
        half = np.abs(self.T_tcp_part[:3, :3]) @ half
        return c - half, c + half


@dataclass(frozen=True)
class ParallelJawGeometry:
    """Dimensions of the parallel-jaw gripper [m], [kg], [N] (defaults: a Robotiq 2F-85 class gripper).

    Attributes:
        stroke_m: full opening between the pad faces (each finger travels half of it).
        palm_z_m: distance from the flange to the underside of the housing (where the fingers start).
        finger_length_m: finger length below the palm.
        pad_size_m: (width along x, thickness along y, length along z) of each pad.
        housing_half_m: half extents of the housing box (x, y, z).
        housing_mass_kg, finger_mass_kg: masses.
        min_force_n, max_force_n: accepted grip-force range per finger (2F-85: 20-235 N).
        close_speed_m_s: finger speed while closing (2F-85: 20-150 mm/s).
        finger_thickness_m: thickness of the finger plate behind each pad (along y).
        finger_width_margin_m: the finger plate is this much wider than the pad on each side (along x).
        coupling_radius_m, coupling_height_m: the flange coupling disc between flange and housing.
    """

    stroke_m: float = 0.085
    palm_z_m: float = 0.10
    finger_length_m: float = 0.06
    pad_size_m: tuple[float, float, float] = (0.022, 0.006, 0.030)
    housing_half_m: tuple[float, float, float] = (0.035, 0.05, 0.045)
    housing_mass_kg: float = 0.75
    finger_mass_kg: float = 0.08
    min_force_n: float = 20.0
    max_force_n: float = 235.0
    close_speed_m_s: float = 0.1
    finger_thickness_m: float = 0.008
    finger_width_margin_m: float = 0.002
    coupling_radius_m: float = 0.038
    coupling_height_m: float = 0.01

    kind = "parallel_jaw"

    def __post_init__(self) -> None:
        values = (self.stroke_m, self.palm_z_m, self.finger_length_m, *self.pad_size_m, *self.housing_half_m)
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise InvalidInputError(f"ParallelJawGeometry dimensions must be finite and > 0 m, got {self}")
        if self.pad_size_m[2] > self.finger_length_m:
            raise InvalidInputError("ParallelJawGeometry: the pad cannot be longer than the finger")

    @property
    def pad_depth_m(self) -> float:
        """Length of a pad along the approach (tcp z) [m]."""
        return float(self.pad_size_m[2])

    def holding_force_n(self, jaw_force_n: float) -> float:
        """The force the gripper closes with: the jaw force per finger asked for [N]."""
        return float(jaw_force_n)

    @property
    def tcp_z_m(self) -> float:
        """Distance from the flange to the tcp (centre of the pads) along flange z [m]."""
        return self.palm_z_m + self.finger_length_m - self.pad_size_m[2] / 2.0

    @property
    def T_flange_tcp(self) -> np.ndarray:
        """(4, 4) tcp pose in the flange frame (a translation along flange z)."""
        return make_T(np.eye(3), [0.0, 0.0, self.tcp_z_m])

    @property
    def palm_to_tcp_m(self) -> float:
        """Distance from the palm (housing underside) down to the tcp along the approach [m]."""
        return self.tcp_z_m - self.palm_z_m

    @property
    def fingertip_below_tcp_m(self) -> float:
        """How far the fingertips reach past the tcp along the approach [m] (half a pad length)."""
        return self.palm_z_m + self.finger_length_m - self.tcp_z_m

    def check_opening(self, opening_m: float) -> float:
        opening_m = float(opening_m)
        if not (math.isfinite(opening_m) and 0.0 <= opening_m <= self.stroke_m + 1e-12):
            raise InvalidInputError(f"opening_m must be within [0, {self.stroke_m}] m, got {opening_m!r}")
        return opening_m

    def parts(self, opening_m: float | None = None) -> tuple[GripperPart, ...]:
        """The sim's collision primitives at pad-face distance `opening_m` (default: open), tcp frame."""
        q = (self.stroke_m if opening_m is None else self.check_opening(opening_m)) / 2.0
        z0 = -self.tcp_z_m  # the flange, in tcp coordinates
        hx, hy, hz = self.housing_half_m
        pw, pt, pl = self.pad_size_m
        ft, fl = self.finger_thickness_m, self.finger_length_m
        ch = self.coupling_height_m / 2.0
        out = [
            GripperPart(
                "gripper_coupling",
                "cylinder",
                (self.coupling_radius_m, ch, 0.0),
                make_T(np.eye(3), [0, 0, z0 + ch]),
                "palm",
            ),
            GripperPart(
                "gripper_housing",
                "box",
                (hx, hy, hz),
                make_T(np.eye(3), [0, 0, z0 + self.palm_z_m - hz]),
                "palm",
            ),
        ]
        z_finger = z0 + self.palm_z_m  # finger body origin (at the palm)
        for side, sign in (("left", 1.0), ("right", -1.0)):
            out.append(
                GripperPart(
                    f"finger_{side}_plate",
                    "box",
                    (pw / 2.0 + self.finger_width_margin_m, ft / 2.0, fl / 2.0),
                    make_T(np.eye(3), [0.0, sign * (q + pt + ft / 2.0), z_finger + fl / 2.0]),
                    f"finger_{side}",
                )
            )
            out.append(
                GripperPart(
                    f"pad_{side}",
                    "box",
                    (pw / 2.0, pt / 2.0, pl / 2.0),
                    make_T(np.eye(3), [0.0, sign * (q + pt / 2.0), z_finger + fl - pl / 2.0]),
                    f"finger_{side}",
                )
            )
        return tuple(out)

    def hull_boxes(self, opening_m: float | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{group: (lo, hi)}: tcp-aligned boxes containing the palm and each finger at `opening_m` [m]."""
        return _group_bounds(self.parts(opening_m))

    def pad_centres_tcp(self, opening_m: float) -> np.ndarray:
        """(2, 3) centres of the left (+y) and right (-y) pad faces in the tcp frame [m]."""
        q = self.check_opening(opening_m) / 2.0
        return np.array([[0.0, q, 0.0], [0.0, -q, 0.0]])


@dataclass(frozen=True)
class SuctionCupGeometry:
    """Dimensions and holding limits of the suction cup [m], [kg], [N].

    Attributes:
        cup_radius_m: radius of the cup face (50 mm cup).
        cup_height_m: thickness of the cup lip.
        stem_length_m: from the flange to the cup (the tcp sits at stem + cup height).
        stem_radius_m: stem radius.
        mass_kg: mass of stem and cup.
        max_force_n: largest load the vacuum holds (about 60 kPa over a 50 mm cup: 118 N).
        max_face_angle_deg: the cup seals only on a face whose normal is within this angle of the cup axis.
        lip_friction: friction coefficient of the lip; the cup holds a shear load up to lip_friction x
            (holding force - pull).
        body_radius_m, body_height_m: the vacuum generator body at the flange.
        compliance_m: how far the bellows give along the cup axis when pressed onto a face; a planned
            contact may be this much off along the approach and still seal.
    """

    cup_radius_m: float = 0.025
    cup_height_m: float = 0.012
    stem_length_m: float = 0.088
    stem_radius_m: float = 0.012
    mass_kg: float = 0.35
    max_force_n: float = 118.0
    max_face_angle_deg: float = 15.0
    lip_friction: float = 0.8
    body_radius_m: float = 0.035
    body_height_m: float = 0.04
    compliance_m: float = 0.01

    kind = "suction"

    def __post_init__(self) -> None:
        values = [self.cup_radius_m, self.cup_height_m, self.stem_length_m, self.stem_radius_m]
        values.append(self.max_force_n)
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise InvalidInputError(f"SuctionCupGeometry dimensions must be finite and > 0, got {self}")

    def holding_force_n(self, jaw_force_n: float) -> float:
        """The force the gripper closes with: the cup's full `max_force_n` (vacuum on; a jaw force does not
        apply) [N]."""
        return float(self.max_force_n)

    @property
    def tcp_z_m(self) -> float:
        """Distance from the flange to the cup face along flange z [m]."""
        return self.stem_length_m + self.cup_height_m

    @property
    def T_flange_tcp(self) -> np.ndarray:
        """(4, 4) tcp pose in the flange frame (a translation along flange z)."""
        return make_T(np.eye(3), [0.0, 0.0, self.tcp_z_m])

    @property
    def stroke_m(self) -> float:
        """A suction cup has no jaws (0 m)."""
        return 0.0

    def max_payload_kg(self, safety_factor: float = 2.0, lateral_g: float = 0.0) -> float:
        """Heaviest object [kg] held top-down with `safety_factor` on the pull, under a lateral acceleration
        of `lateral_g` x g (transfer moves): the pull is m g (1), the shear m g lateral_g, and the shear must
        stay below lip_friction x (holding force - pull)."""
        pull_limit = self.max_force_n / (safety_factor * GRAVITY_M_S2)
        if lateral_g <= 0.0:
            return pull_limit
        # m g lateral <= mu (F - m g) / s  ->  m <= mu F / (g (s lateral + mu))
        shear_limit = (
            self.lip_friction
            * self.max_force_n
            / (GRAVITY_M_S2 * (safety_factor * lateral_g + self.lip_friction))
        )
        return min(pull_limit, shear_limit)

    def parts(self, opening_m: float | None = None) -> tuple[GripperPart, ...]:
        """The sim's collision primitives in the tcp frame (`opening_m` is ignored: no jaws)."""
        z0 = -self.tcp_z_m
        bh = self.body_height_m / 2.0
        stem_half = (self.stem_length_m - self.body_height_m) / 2.0
        return (
            GripperPart(
                "suction_body",
                "cylinder",
                (self.body_radius_m, bh, 0.0),
                make_T(np.eye(3), [0, 0, z0 + bh]),
                "palm",
            ),
            GripperPart(
                "suction_stem",
                "cylinder",
                (self.stem_radius_m, stem_half, 0.0),
                make_T(np.eye(3), [0, 0, -self.cup_height_m - stem_half]),
                "palm",
            ),
            GripperPart(
                "suction_cup_face",
                "cylinder",
                (self.cup_radius_m, self.cup_height_m / 2.0, 0.0),
                make_T(np.eye(3), [0, 0, -self.cup_height_m / 2.0]),
                "cup",
            ),
        )

    def hull_boxes(self, opening_m: float | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{group: (lo, hi)}: tcp-aligned boxes containing the body + stem ("palm") and the cup ("cup")."""
        return _group_bounds(self.parts())


GripperGeometry = ParallelJawGeometry | SuctionCupGeometry

#: The gripper geometry types by kind (the string of config files and the command line).
_GRIPPER_TYPES: dict[str, type[ParallelJawGeometry] | type[SuctionCupGeometry]] = {
    t.kind: t for t in (ParallelJawGeometry, SuctionCupGeometry)
}

#: Gripper kinds and their default geometry.
GRIPPER_KINDS: tuple[str, ...] = tuple(_GRIPPER_TYPES)

#: T_flange_tcp (4, 4) of each gripper type with its default geometry.
GRIPPER_TCP: dict[str, np.ndarray] = {kind: t().T_flange_tcp for kind, t in _GRIPPER_TYPES.items()}


def get_gripper(kind: str) -> ParallelJawGeometry | SuctionCupGeometry:
    """The default geometry of a gripper kind ("parallel_jaw" or "suction")."""
    if not isinstance(kind, str) or kind not in _GRIPPER_TYPES:
        raise UnknownNameError("gripper", kind, GRIPPER_KINDS)
    return _GRIPPER_TYPES[kind]()


def as_gripper(gripper: object) -> ParallelJawGeometry | SuctionCupGeometry:
    """A gripper geometry from a geometry (returned as is) or a kind ("parallel_jaw", "suction": its default
    geometry), for the planners' `gripper` argument."""
    if isinstance(gripper, str):
        return get_gripper(gripper)
    if not isinstance(gripper, (ParallelJawGeometry, SuctionCupGeometry)):
        raise InvalidInputError(
            "gripper must be 'parallel_jaw', 'suction', a ParallelJawGeometry or a SuctionCupGeometry, "
            f"got {type(gripper).__name__}"
        )
    return gripper


def _group_bounds(parts: tuple[GripperPart, ...]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for part in parts:
        lo, hi = part.aabb_tcp()
        if part.group in out:
            lo, hi = np.minimum(out[part.group][0], lo), np.maximum(out[part.group][1], hi)
        out[part.group] = (lo, hi)
    return out
