"""The Universal Robots family from one table: DH parameters, joint limits, speed limits, link geometry.

Every other description of a UR arm in this package (the URDF, the Pinocchio model, the MuJoCo model, the
closed-form kinematics) is generated from the `URSpec` entries below, so they cannot drift apart.

DH convention (standard / distal, as in UR's own "DH parameters for calculations of kinematics and dynamics"):
frame i is reached from frame i-1 by ``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. Frame 0 is `base`, the frame
the UR controller reports poses in (``getActualTCPPose``); frame 6 is `flange` (ROS ``tool0``). ROS'
``base_link`` is `base` rotated by pi about z; nothing here uses it.

Joint limits: +-2 pi on every joint except the elbow, which is limited to +-pi. The forearm cannot pass
through the upper arm, so an elbow angle beyond pi is never a different posture, only a self-collision;
ur_description uses the same range. With it the closed-form elbow angle (an arccos, in [-pi, pi]) maps to
exactly one joint value, and the two elbow branches are q[2] > 0 and q[2] < 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from prompose_grasp.errors import UnknownNameError

#: Joint names, base to wrist, as in ur_description and the UR controller.
JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)

#: Link names: `base` (DH frame 0, fixed), the six moving links, then `flange` (DH frame 6, ROS tool0).
LINK_NAMES: tuple[str, ...] = (
    "base",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)

FLANGE_NAME = "flange"
TCP_NAME = "tcp"

#: alpha is the same for every UR arm [rad].
UR_ALPHA: tuple[float, ...] = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)

_TWO_PI = 2.0 * np.pi


def _as_tuple(values: object, n: int, name: str) -> tuple[float, ...]:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must hold {n} finite numbers, got {values!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class URSpec:
    """One UR model: everything needed to generate its URDF, MuJoCo model and closed-form kinematics.

    Attributes:
        name: registry key, lower case ("ur5e").
        d_m: (6,) DH offsets d1..d6 [m] (d2 = d3 = 0 on every UR).
        a_m: (6,) DH lengths a1..a6 [m] (a2, a3 negative in UR's convention; the rest 0).
        alpha_rad: (6,) DH twists [rad].
        max_joint_speed_rad_s: (6,) joint speed limits from the UR data sheet [rad/s].
        link_mass_kg: (6,) masses of shoulder .. wrist_3 from UR's dynamics table [kg].
        max_joint_torque_nm: (6,) nominal joint torque limits (the `effort` of ur_description) [N m].
        capsule_radius_m: radii of the collision capsules (base, shoulder, upper arm, forearm, wrists) [m],
            sized from the outer diameter of the joint housings and tubes of the real arm.
        joint_lower_rad, joint_upper_rad: (6,) position limits [rad] (see the module docstring for the elbow).
    """

    name: str
    d_m: tuple[float, ...]
    a_m: tuple[float, ...]
    max_joint_speed_rad_s: tuple[float, ...]
    link_mass_kg: tuple[float, ...]
    max_joint_torque_nm: tuple[float, ...]
    capsule_radius_m: tuple[float, ...]
    alpha_rad: tuple[float, ...] = UR_ALPHA
    joint_lower_rad: tuple[float, ...] = (-_TWO_PI, -_TWO_PI, -np.pi, -_TWO_PI, -_TWO_PI, -_TWO_PI)
    joint_upper_rad: tuple[float, ...] = (_TWO_PI, _TWO_PI, np.pi, _TWO_PI, _TWO_PI, _TWO_PI)
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        for attr, n in (
            ("d_m", 6),
            ("a_m", 6),
            ("alpha_rad", 6),
            ("max_joint_speed_rad_s", 6),
            ("link_mass_kg", 6),
            ("max_joint_torque_nm", 6),
            ("capsule_radius_m", 5),
            ("joint_lower_rad", 6),
            ("joint_upper_rad", 6),
        ):
            object.__setattr__(self, attr, _as_tuple(getattr(self, attr), n, f"{self.name}.{attr}"))
        if any(lo >= hi for lo, hi in zip(self.joint_lower_rad, self.joint_upper_rad)):
            raise ValueError(f"{self.name}: every joint needs lower < upper")
        if min(self.max_joint_speed_rad_s) <= 0 or min(self.link_mass_kg) <= 0:
            raise ValueError(f"{self.name}: speed limits and masses must be positive")

    # Named accessors for the six non-trivial DH numbers, as UR's table lists them.
    @property
    def d1(self) -> float:
        return self.d_m[0]

    @property
    def a2(self) -> float:
        return self.a_m[1]

    @property
    def a3(self) -> float:
        return self.a_m[2]

    @property
    def d4(self) -> float:
        return self.d_m[3]

    @property
    def d5(self) -> float:
        return self.d_m[4]

    @property
    def d6(self) -> float:
        return self.d_m[5]

    @property
    def reach_m(self) -> float:
        """Distance from the shoulder axis to the flange with the arm stretched out [m] (an upper bound)."""
        return abs(self.a2) + abs(self.a3) + float(np.hypot(self.d4, np.hypot(self.d5, self.d6)))

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (6,) float64 [rad]."""
        return np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)


def _ur(
    name: str,
    d1: float,
    a2: float,
    a3: float,
    d4: float,
    d5: float,
    d6: float,
    speed: tuple[float, ...],
    mass: tuple[float, ...],
    torque: tuple[float, ...],
    radius: tuple[float, ...],
    description: str,
) -> URSpec:
    return URSpec(
        name=name,
        d_m=(d1, 0.0, 0.0, d4, d5, d6),
        a_m=(0.0, a2, a3, 0.0, 0.0, 0.0),
        max_joint_speed_rad_s=speed,
        link_mass_kg=mass,
        max_joint_torque_nm=torque,
        capsule_radius_m=radius,
        description=description,
    )


_PI = np.pi
_SLOW = 2.0 * np.pi / 3.0

#: The registry. DH numbers are UR's official ones (metres); speeds from the UR data sheets.
UR_MODELS: dict[str, URSpec] = {
    spec.name: spec
    for spec in (
        _ur(
            "ur3e", 0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921,
            speed=(_PI, _PI, _PI, 2 * _PI, 2 * _PI, 2 * _PI),
            mass=(1.98, 3.4445, 1.437, 0.871, 0.805, 0.261),
            torque=(56.0, 56.0, 28.0, 12.0, 12.0, 12.0),
            radius=(0.065, 0.06, 0.05, 0.04, 0.035),
            description="UR3e, 3 kg payload, 500 mm reach",
        ),
        _ur(
            "ur5e", 0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996,
            speed=(_PI,) * 6,
            mass=(3.761, 8.058, 2.846, 1.37, 1.3, 0.365),
            torque=(150.0, 150.0, 150.0, 28.0, 28.0, 28.0),
            radius=(0.075, 0.075, 0.06, 0.05, 0.045),
            description="UR5e, 5 kg payload, 850 mm reach (default)",
        ),
        _ur(
            "ur10e", 0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655,
            speed=(_SLOW, _SLOW, _PI, _PI, _PI, _PI),
            mass=(7.369, 13.051, 3.989, 2.1, 1.98, 0.615),
            torque=(330.0, 330.0, 150.0, 56.0, 56.0, 56.0),
            radius=(0.09, 0.09, 0.075, 0.06, 0.05),
            description="UR10e, 12.5 kg payload, 1300 mm reach",
        ),
        _ur(
            "ur16e", 0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655,
            speed=(_SLOW, _SLOW, _PI, _PI, _PI, _PI),
            mass=(7.369, 10.45, 4.321, 2.18, 2.033, 0.907),
            torque=(330.0, 330.0, 150.0, 54.0, 54.0, 54.0),
            radius=(0.09, 0.09, 0.075, 0.06, 0.05),
            description="UR16e, 16 kg payload, 900 mm reach",
        ),
        _ur(
            "ur5", 0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823,
            speed=(_PI,) * 6,
            mass=(3.7, 8.393, 2.33, 1.219, 1.219, 0.1879),
            torque=(150.0, 150.0, 150.0, 28.0, 28.0, 28.0),
            radius=(0.075, 0.075, 0.06, 0.05, 0.045),
            description="UR5 (CB3), 5 kg payload, 850 mm reach",
        ),
    )
}  # fmt: skip

DEFAULT_ROBOT = "ur5e"


def get_ur_spec(name: str = DEFAULT_ROBOT) -> URSpec:
    """The `URSpec` registered under `name` (case-insensitive); `UnknownNameError` lists the known ones."""
    key = name.lower().strip() if isinstance(name, str) else name
    if key not in UR_MODELS:
        raise UnknownNameError("robot", name, UR_MODELS)
    return UR_MODELS[key]


def known_robots() -> tuple[str, ...]:
    """Names accepted by `get_ur_spec` and `load_robot`."""
    return tuple(UR_MODELS)
