"""DH table -> kinematic description -> URDF text, and the URDF reader the MuJoCo builder uses.

The one source of truth for a UR arm's geometry is its `URSpec`. `describe_arm` turns it into an
`ArmDescription` (links with inertials and collision capsules, joints with origins); `urdf_from_description`
writes that as URDF; `parse_urdf` reads such a URDF back. Pinocchio is built from the URDF text and MuJoCo
from the description parsed out of the same text, so both see the same numbers.

Standard DH puts the joint rotation *before* the fixed part of each link transform
(frame_i = frame_{i-1} Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)), while a URDF joint rotates *after* its fixed
origin. So URDF link i's frame is DH frame i-1 rotated by q_i, and joint i+1's origin is the fixed part
Tz(d_i) Tx(a_i) Rx(alpha_i) = (xyz = (a_i, 0, d_i), rpy = (alpha_i, 0, 0)), written exactly. A fixed joint
with the last fixed part gives `flange` = DH frame 6. Floats are written with `repr` (exact round trip).

Collision capsules are written in standard URDF as a cylinder (the capsule's body) plus a sphere at each end;
their union is exactly the capsule, every URDF parser understands them, and `parse_urdf` joins them back into
one capsule by name (`<link>_capsule<k>`, `..._cap_a`, `..._cap_b`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.robot.ur_models import FLANGE_NAME, JOINT_NAMES, LINK_NAMES, URSpec

# Links whose capsules sit on or next to the mounting surface; support-plane avoidance skips them.
BASE_LINKS: tuple[str, ...] = ("base", "shoulder_link")


@dataclass(frozen=True)
class Capsule:
    """A capsule in its link's frame: the segment p0 -> p1 (each (3,) [m]) swept by a sphere of `radius_m`."""

    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius_m: float

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.p1, self.p0)))


@dataclass(frozen=True)
class Inertial:
    """Mass [kg] at `com_xyz` [m] (link frame); principal moments `inertia_diag` [kg m^2] along axes `rpy`."""

    mass_kg: float
    com_xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    inertia_diag: tuple[float, float, float]


@dataclass(frozen=True)
class LinkDescription:
    name: str
    inertial: Inertial | None
    capsules: tuple[Capsule, ...]


@dataclass(frozen=True)
class JointDescription:
    """A URDF joint: `child` frame = `parent` frame @ origin(xyz [m], rpy [rad]) @ Rot(axis, q)."""

    name: str
    type: str  # "revolute" or "fixed"
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    lower_rad: float = 0.0
    upper_rad: float = 0.0
    velocity_rad_s: float = 0.0
    effort_nm: float = 0.0


@dataclass(frozen=True)
class ArmDescription:
    """A serial arm as a tree of links and joints, root link first and joints in chain order."""

    name: str
    links: tuple[LinkDescription, ...]
    joints: tuple[JointDescription, ...]

    @property
    def root(self) -> str:
        return self.links[0].name

    def link(self, name: str) -> LinkDescription:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)


def _fixed_part(spec: URSpec, i: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """xyz, rpy of Tz(d_i) Tx(a_i) Rx(alpha_i) for DH row i (0-based)."""
    return (spec.a_m[i], 0.0, spec.d_m[i]), (spec.alpha_rad[i], 0.0, 0.0)


def _dh_point_to_link(spec: URSpec, i: int, p_dh: tuple[float, float, float]) -> tuple[float, float, float]:
    """A point in DH frame i (1-based, i >= 1) expressed in URDF link i's frame: Tz(d)Tx(a)Rx(alpha) @ p."""
    xyz, rpy = _fixed_part(spec, i - 1)
    p = Rotation.from_euler("x", rpy[0]).apply(np.asarray(p_dh, dtype=np.float64)) + np.asarray(xyz)
    return (float(p[0]), float(p[1]), float(p[2]))


def _capsules_dh(
    spec: URSpec,
) -> list[tuple[int, tuple[float, float, float], tuple[float, float, float], float]]:
    """(DH frame index, p0, p1, radius) of each link's capsule, written in that link's DH frame.

    The capsules follow the DH skeleton: the upper arm and forearm tubes run between the joint centres in the
    plane of joint 2, and the wrist housings bridge the d4, d5, d6 offsets. The real arm carries its tubes at
    axial offsets that DH lumps into d4; those offsets are horizontal, so heights above a support plane match.
    """
    r_base, r_shoulder, r_upper, r_fore, r_wrist = spec.capsule_radius_m
    d1, a2, a3, d4, d5, d6 = spec.d1, spec.a2, spec.a3, spec.d4, spec.d5, spec.d6
    return [
        (0, (0.0, 0.0, r_base), (0.0, 0.0, d1), r_base),
        (1, (0.0, 0.0, -0.5 * r_shoulder), (0.0, 0.0, 0.5 * r_shoulder), r_shoulder),
        (2, (-a2, 0.0, 0.0), (0.0, 0.0, 0.0), r_upper),
        (3, (-a3, 0.0, 0.0), (0.0, 0.0, 0.0), r_fore),
        (4, (0.0, -d4, 0.0), (0.0, 0.0, 0.0), r_wrist),
        (5, (0.0, d5, 0.0), (0.0, 0.0, 0.0), r_wrist),
        # The wrist-3 housing ends at the flange face (z = 0), so its cap never pokes past the tool mount.
        (6, (0.0, 0.0, -d6), (0.0, 0.0, -r_wrist), r_wrist),
    ]


def _axis_rotation(direction: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is `direction` (unit (3,))."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def rpy_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw [rad] of a rotation, R = Rz(yaw) Ry(pitch) Rx(roll); inverse of
    `rotation_from_rpy`.

    At pitch = +-pi/2 (gimbal lock; common here, capsules often lie along x) roll is set to 0 and yaw takes
    the rest.
    """
    pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    if math.hypot(R[0, 0], R[1, 0]) < 1e-12:
        return (0.0, pitch, math.atan2(-R[0, 1], R[1, 1]))
    return (math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0]))


_rpy_of = rpy_from_rotation


def _cylinder_inertial(mass_kg: float, capsule: Capsule) -> Inertial:
    """A solid cylinder the size of the capsule, centred on it: a fair spread for a hollow tube + motors."""
    p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
    r, length = capsule.radius_m, capsule.length_m + capsule.radius_m
    i_axial = 0.5 * mass_kg * r**2
    i_trans = mass_kg * (3.0 * r**2 + length**2) / 12.0
    com = 0.5 * (p0 + p1)
    return Inertial(
        mass_kg=mass_kg,
        com_xyz=(float(com[0]), float(com[1]), float(com[2])),
        rpy=_rpy_of(_axis_rotation(p1 - p0)),
        inertia_diag=(i_trans, i_trans, i_axial),
    )


def describe_arm(spec: URSpec) -> ArmDescription:
    """The kinematic + inertial + collision description of a UR arm, generated from its DH table."""
    capsules_by_link: dict[str, Capsule] = {}
    for i, p0, p1, radius in _capsules_dh(spec):
        if i > 0:
            p0, p1 = _dh_point_to_link(spec, i, p0), _dh_point_to_link(spec, i, p1)
        capsules_by_link[LINK_NAMES[i]] = Capsule(p0=p0, p1=p1, radius_m=radius)

    links = [LinkDescription("base", None, (capsules_by_link["base"],))]
    for k, name in enumerate(LINK_NAMES[1:]):
        capsule = capsules_by_link[name]
        links.append(LinkDescription(name, _cylinder_inertial(spec.link_mass_kg[k], capsule), (capsule,)))
    links.append(LinkDescription(FLANGE_NAME, None, ()))

    joints = []
    for k, name in enumerate(JOINT_NAMES):
        xyz, rpy = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)) if k == 0 else _fixed_part(spec, k - 1)
        joints.append(
            JointDescription(
                name=name,
                type="revolute",
                parent=LINK_NAMES[k],
                child=LINK_NAMES[k + 1],
                xyz=xyz,
                rpy=rpy,
                lower_rad=spec.joint_lower_rad[k],
                upper_rad=spec.joint_upper_rad[k],
                velocity_rad_s=spec.max_joint_speed_rad_s[k],
                effort_nm=spec.max_joint_torque_nm[k],
            )
        )
    xyz, rpy = _fixed_part(spec, 5)
    joints.append(JointDescription("flange_joint", "fixed", LINK_NAMES[-1], FLANGE_NAME, xyz, rpy))
    return ArmDescription(name=spec.name, links=tuple(links), joints=tuple(joints))


def _fmt(values: tuple[float, ...] | list[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def urdf_from_description(desc: ArmDescription) -> str:
    """URDF XML text of an `ArmDescription` (standard URDF 1.0 elements only)."""
    robot = ET.Element("robot", name=desc.name)
    for link in desc.links:
        el = ET.SubElement(robot, "link", name=link.name)
        if link.inertial is not None:
            inertial = ET.SubElement(el, "inertial")
            ET.SubElement(inertial, "origin", xyz=_fmt(link.inertial.com_xyz), rpy=_fmt(link.inertial.rpy))
            ET.SubElement(inertial, "mass", value=repr(link.inertial.mass_kg))
            ixx, iyy, izz = link.inertial.inertia_diag
            ET.SubElement(
                inertial,
                "inertia",
                ixx=repr(ixx),
                ixy="0.0",
                ixz="0.0",
                iyy=repr(iyy),
                iyz="0.0",
                izz=repr(izz),
            )
        for k, capsule in enumerate(link.capsules):
            p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
            rpy = _rpy_of(_axis_rotation(p1 - p0))
            base = f"{link.name}_capsule{k}"
            for name, xyz, geom, attrs in (
                (
                    base,
                    0.5 * (p0 + p1),
                    "cylinder",
                    {"radius": repr(capsule.radius_m), "length": repr(capsule.length_m)},
                ),
                (f"{base}_cap_a", p0, "sphere", {"radius": repr(capsule.radius_m)}),
                (f"{base}_cap_b", p1, "sphere", {"radius": repr(capsule.radius_m)}),
            ):
                col = ET.SubElement(el, "collision", name=name)
                ET.SubElement(col, "origin", xyz=_fmt(list(xyz)), rpy=_fmt(rpy))
                ET.SubElement(ET.SubElement(col, "geometry"), geom, attrib=attrs)
    for joint in desc.joints:
        el = ET.SubElement(robot, "joint", name=joint.name, type=joint.type)
        ET.SubElement(el, "parent", link=joint.parent)
        ET.SubElement(el, "child", link=joint.child)
        ET.SubElement(el, "origin", xyz=_fmt(joint.xyz), rpy=_fmt(joint.rpy))
        ET.SubElement(el, "axis", xyz=_fmt(joint.axis))  # ignored on fixed joints; written so it round-trips
        if joint.type == "revolute":
            ET.SubElement(
                el,
                "limit",
                lower=repr(joint.lower_rad),
                upper=repr(joint.upper_rad),
                velocity=repr(joint.velocity_rad_s),
                effort=repr(joint.effort_nm),
            )
    ET.indent(robot)
    return ET.tostring(robot, encoding="unicode")


def ur_urdf(spec: URSpec) -> str:
    """URDF text of a UR arm, generated from its DH table."""
    return urdf_from_description(describe_arm(spec))


def _floats(text: str | None, n: int, what: str) -> tuple[float, ...]:
    values = tuple(float(v) for v in (text or "").split())
    if len(values) != n:
        raise InvalidInputError(f"URDF {what} needs {n} numbers, got {text!r}")
    return values


def _origin(el: ET.Element | None) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    if el is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    xyz = _floats(el.get("xyz", "0 0 0"), 3, "origin xyz")
    rpy = _floats(el.get("rpy", "0 0 0"), 3, "origin rpy")
    return (xyz[0], xyz[1], xyz[2]), (rpy[0], rpy[1], rpy[2])


def _parse_link(el: ET.Element) -> LinkDescription:
    name = el.get("name", "")
    inertial = None
    inertial_el = el.find("inertial")
    if inertial_el is not None:
        com, rpy = _origin(inertial_el.find("origin"))
        mass_el, inertia_el = inertial_el.find("mass"), inertial_el.find("inertia")
        if mass_el is None or inertia_el is None:
            raise InvalidInputError(f"URDF link {name!r}: <inertial> needs <mass> and <inertia>")
        off_diagonal = [float(inertia_el.get(k, "0")) for k in ("ixy", "ixz", "iyz")]
        if any(abs(v) > 0.0 for v in off_diagonal):
            raise InvalidInputError(
                f"URDF link {name!r}: only principal-axis inertias (ixy = ixz = iyz = 0) are read"
            )
        inertial = Inertial(
            mass_kg=float(mass_el.get("value", "nan")),
            com_xyz=com,
            rpy=rpy,
            inertia_diag=tuple(float(inertia_el.get(k, "nan")) for k in ("ixx", "iyy", "izz")),  # type: ignore[arg-type]
        )
    capsules = []
    for col in el.findall("collision"):
        col_name = col.get("name", "")
        if col_name.endswith(("_cap_a", "_cap_b")):
            continue  # the end spheres are implied by the capsule body
        cyl = col.find("geometry/cylinder")
        if cyl is None:
            raise InvalidInputError(
                f"URDF link {name!r}: collision {col_name!r} is not a capsule body cylinder"
            )
        xyz, rpy = _origin(col.find("origin"))
        half = 0.5 * float(cyl.get("length", "nan"))
        axis = Rotation.from_euler("xyz", rpy).apply([0.0, 0.0, half])
        p0, p1 = np.asarray(xyz) - axis, np.asarray(xyz) + axis
        capsules.append(
            Capsule(
                p0=(float(p0[0]), float(p0[1]), float(p0[2])),
                p1=(float(p1[0]), float(p1[1]), float(p1[2])),
                radius_m=float(cyl.get("radius", "nan")),
            )
        )
    return LinkDescription(name=name, inertial=inertial, capsules=tuple(capsules))


def parse_urdf(text: str) -> ArmDescription:
    """Read a serial-arm URDF as written by `urdf_from_description` (revolute/fixed joints, capsules)."""
    try:
        robot = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InvalidInputError(f"not valid URDF XML: {exc}") from exc
    links = {el.get("name", ""): _parse_link(el) for el in robot.findall("link")}
    joints: dict[str, JointDescription] = {}
    for el in robot.findall("joint"):
        jtype = el.get("type", "")
        if jtype not in ("revolute", "fixed"):
            raise InvalidInputError(
                f"URDF joint {el.get('name')!r}: type {jtype!r}; accepted: revolute, fixed"
            )
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None:
            raise InvalidInputError(f"URDF joint {el.get('name')!r} needs <parent> and <child>")
        xyz, rpy = _origin(el.find("origin"))
        limit = el.find("limit")
        axis_el = el.find("axis")
        axis = _floats(axis_el.get("xyz") if axis_el is not None else "1 0 0", 3, "axis")
        joints[parent.get("link", "")] = JointDescription(
            name=el.get("name", ""),
            type=jtype,
            parent=parent.get("link", ""),
            child=child.get("link", ""),
            xyz=xyz,
            rpy=rpy,
            axis=(axis[0], axis[1], axis[2]),
            lower_rad=float(limit.get("lower", "0")) if limit is not None else 0.0,
            upper_rad=float(limit.get("upper", "0")) if limit is not None else 0.0,
            velocity_rad_s=float(limit.get("velocity", "0")) if limit is not None else 0.0,
            effort_nm=float(limit.get("effort", "0")) if limit is not None else 0.0,
        )
    children = {j.child for j in joints.values()}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise InvalidInputError(f"URDF must describe one tree with one root link, found roots {roots}")
    # Walk the chain from the root; a serial arm has at most one joint per parent link.
    ordered_links, ordered_joints = [links[roots[0]]], []
    current = roots[0]
    while current in joints:
        joint = joints[current]
        ordered_joints.append(joint)
        current = joint.child
        ordered_links.append(links[current])
    if len(ordered_links) != len(links):
        raise InvalidInputError("URDF is not a serial chain (branches or disconnected links)")
    return ArmDescription(
        name=robot.get("name", ""), links=tuple(ordered_links), joints=tuple(ordered_joints)
    )


def rotation_from_rpy(rpy: tuple[float, float, float]) -> np.ndarray:
    """(3, 3) rotation of URDF roll-pitch-yaw [rad]: Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
