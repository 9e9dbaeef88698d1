"""Put a UR arm and its gripper into a scene: `add_robot(builder, "ur5e", T_world_base, gripper=...)`.

The arm comes from the robot layer (`prompose_grasp.robot.add_arm_to_spec` with the URDF that Pinocchio and
the closed-form kinematics also use), so the sim's flange pose and `RobotModel.fk` agree to numerical
precision. What this module adds for simulation:

- joint position servos (MuJoCo position actuators, force-limited to the joint torque limits) with per-joint
  stiffness `kp = ARM_KP_PER_NM * torque limit` and damping `kv = ARM_KV_PER_NM * torque limit`, reflected
  motor inertia (`armature`) proportional to the torque limit, and gravity compensation of the arm and gripper
  bodies (`body.gravcomp`, MuJoCo's exact per-body compensation); `SimArm` adds velocity and inertial feed
  forward, so tracking errors stay well below a millimetre at the TCP during normal moves;
- the `implicitfast` integrator (the servo damping is integrated implicitly, stable at stiff gains) and a
  time step of at most 2 ms (control at >= 500 Hz);
- a pedestal from the floor to a raised base (visual and collision);
- the gripper (`sim.grippers`) under the `flange` body, with its TCP as the `RobotModel`'s tcp offset;
- `noslip` iterations for grasping.

Arm and gripper geoms are group 1 with contype 2 / conaffinity 1: they touch the scene but not each other.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import as_transform, invert_T, make_T
from prompose_grasp.robot import HOME_Q, RobotModel, add_arm_to_spec, known_robots, load_robot
from prompose_grasp.robot.ur_models import FLANGE_NAME, JOINT_NAMES
from sim.grippers import (
    GROUP_ROBOT,
    ROBOT_CONAFFINITY,
    ROBOT_CONTYPE,
    ParallelJawGeometry,
    SuctionCupGeometry,
    add_parallel_jaw,
    add_suction_cup,
    add_suction_welds,
)

__all__ = ["ARM_KP_PER_NM", "ARM_KV_PER_NM", "GRIPPER_KINDS", "RobotInfo", "add_robot", "base_pose_facing"]

log = logging.getLogger(__name__)

#: Gripper types a robot can carry (None: a bare flange).
GRIPPER_KINDS = ("parallel_jaw", "suction")
#: Servo stiffness per N m of joint torque limit [1/rad]: UR5e 4500 N m/rad (shoulder), 840 (wrist).
ARM_KP_PER_NM = 30.0
#: Servo damping per N m of torque limit [s/rad]: about critical for the armature below.
ARM_KV_PER_NM = 1.2
#: Reflected motor inertia per N m of torque limit [kg m^2 / (N m)]: UR5e 0.9 (shoulder), 0.17 (wrist).
ARM_ARMATURE_PER_NM = 0.006
#: Largest time step with an arm [s]: the servos run at the physics rate, >= 500 Hz.
MAX_TIMESTEP_S = 0.002


@dataclass(frozen=True, eq=False)
class RobotInfo:
    """The compiled robot of a `SimWorld`: model, pose, and MuJoCo indices.

    Attributes:
        robot: the `RobotModel` (kinematics, IK) whose tcp offset is the gripper's TCP.
        gripper: "parallel_jaw", "suction" or None.
        T_world_base: (4, 4) pose of the arm's `base` in the world [m].
        home_q: (6,) joint positions at reset [rad].
        qpos_adr, dof_adr, actuator_ids: (6,) int indices of the arm joints in qpos, qvel and the actuators.
        kp, kv: (6,) servo stiffness [N m/rad] and damping [N m s/rad].
        flange_body: body id of `flange`.
    """

    robot: RobotModel
    gripper: str | None
    T_world_base: np.ndarray
    home_q: np.ndarray
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    actuator_ids: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    flange_body: int
    _gripper_defaults: dict = field(default_factory=dict, repr=False)
    _finger_qpos: dict = field(default_factory=dict, repr=False)
    _geom_collision: dict = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        return self.robot.name

    @property
    def T_base_world(self) -> np.ndarray:
        return invert_T(self.T_world_base)

    def apply_home(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Arm at `home_q`, at rest, servo targets there; gripper open with its default force limit."""
        data.qpos[self.qpos_adr] = self.home_q
        data.qvel[self.dof_adr] = 0.0
        data.ctrl[self.actuator_ids] = self.home_q
        data.qfrc_applied[self.dof_adr] = 0.0
        for geom, (contype, conaffinity) in self._geom_collision.items():
            model.geom_contype[geom], model.geom_conaffinity[geom] = contype, conaffinity
        for adr, q in self._finger_qpos.items():
            data.qpos[adr] = q
        for act, (forcerange, ctrl) in self._gripper_defaults.items():
            model.actuator_forcerange[act] = forcerange
            data.ctrl[act] = ctrl


@dataclass
class _PendingRobot:
    robot: RobotModel
    gripper: str | None
    T_world_base: np.ndarray
    home_q: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    gripper_open_q: float = 0.0

    def before_compile(self, builder) -> None:
        if self.gripper == "suction":
            add_suction_welds(
                builder.spec, [f"obj_{o.name}" for o in builder.objects if not _is_fixed(builder, o.name)]
            )

    def resolve(self, model: mujoco.MjModel) -> RobotInfo:
        joints = [model.joint(n) for n in JOINT_NAMES]
        qpos_adr = np.array([model.jnt_qposadr[j.id] for j in joints])
        defaults = {}
        finger_qpos: dict[int, float] = {}
        if self.gripper == "parallel_jaw":
            for side in ("left", "right"):
                a = model.actuator(f"finger_{side}_joint").id
                j = model.joint(f"finger_{side}_joint").id
                defaults[a] = (model.actuator_forcerange[a].copy(), self.gripper_open_q)
                finger_qpos[int(model.jnt_qposadr[j])] = self.gripper_open_q
        geom_collision = {}
        if self.gripper == "suction":  # the cup face stops colliding while it holds; reset restores it
            face = model.geom("suction_cup_face").id
            geom_collision[face] = (int(model.geom_contype[face]), int(model.geom_conaffinity[face]))
        # Not model.qpos0: MuJoCo measures hinge angles from qpos0, so changing it would move the kinematics.
        return RobotInfo(
            robot=self.robot,
            gripper=self.gripper,
            T_world_base=self.T_world_base,
            home_q=self.home_q,
            qpos_adr=qpos_adr,
            dof_adr=np.array([model.jnt_dofadr[j.id] for j in joints]),
            actuator_ids=np.array([model.actuator(n).id for n in JOINT_NAMES]),
            kp=self.kp,
            kv=self.kv,
            flange_body=model.body(FLANGE_NAME).id,
            _gripper_defaults=defaults,
            _finger_qpos=finger_qpos,
            _geom_collision=geom_collision,
        )


def _is_fixed(builder, name: str) -> bool:
    body = builder.spec.body(f"obj_{name}")
    return body is None or not any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints)


def add_robot(
    builder,
    robot: str | RobotModel,
    T_world_base: ArrayLike | None = None,
    gripper: str | None = "parallel_jaw",
    home_q: ArrayLike | None = None,
    pedestal: bool = True,
) -> RobotModel:
    """Build a UR arm (and gripper) into `builder.spec`; returns the `RobotModel` whose TCP is the gripper's.

    Args:
        builder: the `SceneBuilder` (one robot per scene).
        robot: "ur3e", "ur5e", "ur10e", "ur16e", "ur5", or a `RobotModel` (its name picks the arm; the tcp
            offset is replaced by the gripper's).
        T_world_base: (4, 4) pose of the arm's `base` (UR controller base frame) in the world [m].
        gripper: "parallel_jaw", "suction" or None (tcp = flange).
        home_q: (6,) joint positions at reset [rad]; `prompose_grasp.robot.HOME_Q` (elbow up, flange down,
            TCP about 0.5 m along base -x for a UR5e) if None.
        pedestal: add a column from the floor (z = 0) to a raised base.
    """
    if builder.spec.option.timestep > MAX_TIMESTEP_S + 1e-12:
        raise InvalidInputError(
            f"a scene with an arm needs timestep_s <= {MAX_TIMESTEP_S} s (servo rate >= 500 Hz); "
            f"this one has {builder.spec.option.timestep} s"
        )
    if getattr(builder, "_robot", None) is not None:
        raise InvalidInputError("this scene already has a robot; add_robot supports one per scene")
    if gripper is not None and gripper not in GRIPPER_KINDS:
        raise UnknownNameError("gripper", gripper, GRIPPER_KINDS)
    name = robot.name if isinstance(robot, RobotModel) else str(robot).lower()
    if name not in known_robots():
        raise UnknownNameError("robot", name, known_robots())
    T_base = np.eye(4) if T_world_base is None else as_transform(T_world_base, "T_world_base")
    q_home = HOME_Q.copy() if home_q is None else np.asarray(home_q, dtype=np.float64)
    if q_home.shape != (6,) or not np.all(np.isfinite(q_home)):
        raise InvalidInputError(f"home_q must be a finite (6,) joint vector [rad], got {home_q!r}")
    builder._unique("robot")  # one robot; also reserves the name

    spec = builder.spec
    # The gripper's TCP becomes the RobotModel's tcp offset (IK and tcp_pose then mean the gripper's TCP).
    if gripper == "parallel_jaw":
        T_flange_tcp = ParallelJawGeometry().T_flange_tcp
    elif gripper == "suction":
        T_flange_tcp = SuctionCupGeometry().T_flange_tcp
    else:
        T_flange_tcp = np.eye(4)
    model = load_robot(name, tcp_offset=T_flange_tcp)
    lower, upper = model.joint_limits
    if np.any(q_home < lower) or np.any(q_home > upper):
        raise InvalidInputError(f"home_q {q_home.tolist()} is outside the joint limits of {name}")

    root = add_arm_to_spec(spec, model.urdf, T_parent_base=T_base, T_flange_tcp=T_flange_tcp, actuator_kp=1.0)
    effort = np.array(model.spec.max_joint_torque_nm, dtype=np.float64)
    kp, kv = ARM_KP_PER_NM * effort, ARM_KV_PER_NM * effort
    for j, jname in enumerate(JOINT_NAMES):
        joint = spec.joint(jname)
        joint.armature = ARM_ARMATURE_PER_NM * effort[j]
        act = spec.actuator(jname)
        act.gainprm = [kp[j]] + [0.0] * 9
        act.biasprm = [0.0, -kp[j], -kv[j]] + [0.0] * 7
        # SimArm adds a velocity feed-forward term (kv/kp * qd) to the target; room for it past the limits.
        act.ctrlrange = [lower[j] - 0.5, upper[j] + 0.5]
    for body in [root, *root.find_all(mujoco.mjtObj.mjOBJ_BODY)]:
        body.gravcomp = 1.0
        for geom in body.geoms:
            geom.group = GROUP_ROBOT
            geom.contype = ROBOT_CONTYPE
            geom.conaffinity = ROBOT_CONAFFINITY
    flange = spec.body(FLANGE_NAME)
    if gripper == "parallel_jaw":
        add_parallel_jaw(spec, flange)
    elif gripper == "suction":
        add_suction_cup(spec, flange)
    for body in flange.find_all(mujoco.mjtObj.mjOBJ_BODY):
        body.gravcomp = 1.0

    if pedestal and T_base[2, 3] > 0.02:
        # A column under the base (it sits on the floor); static like the supports.
        ped = spec.worldbody.add_body(name="robot_pedestal", pos=[T_base[0, 3], T_base[1, 3], 0.0])
        ped.add_geom(
            name="robot_pedestal", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[0.08, T_base[2, 3] / 2.0 - 0.001, 0.0], pos=[0.0, 0.0, T_base[2, 3] / 2.0 - 0.001],
            rgba=[0.3, 0.3, 0.32, 1.0], group=0,
        )  # fmt: skip

    # Integrator and solver settings for a servoed arm and grasping (see the module docstring).
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.noslip_iterations = max(spec.option.noslip_iterations, 3)
    builder._robot = _PendingRobot(
        robot=model,
        gripper=gripper,
        T_world_base=T_base,
        home_q=q_home,
        kp=kp,
        kv=kv,
        gripper_open_q=ParallelJawGeometry().stroke_m / 2.0 if gripper == "parallel_jaw" else 0.0,
    )
    log.info("added %s with %s gripper at %s", name, gripper, np.round(T_base[:3, 3], 3).tolist())
    return model


def base_pose_facing(target_xy_m: ArrayLike, base_xyz_m: ArrayLike) -> np.ndarray:
    """T_world_base (4, 4) at `base_xyz_m` yawed so that base -x (the home reach) faces `target_xy_m`."""
    p = np.asarray(base_xyz_m, dtype=np.float64)
    d = np.asarray(target_xy_m, dtype=np.float64) - p[:2]
    yaw = np.arctan2(d[1], d[0]) + np.pi  # base -x towards the target
    c, s = np.cos(yaw), np.sin(yaw)
    return make_T(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), p)
