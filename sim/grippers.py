"""Simulated grippers: a parallel-jaw gripper (Robotiq 2F-85 class) and a suction cup, as `Gripper` devices.

Both are built into the scene's `MjSpec` under the arm's `flange` body (`add_parallel_jaw`, `add_suction_cup`,
called by `sim.robot_scene.add_robot`) and driven at run time through the compiled `SimWorld`
(`ParallelJawGripper`, `SuctionGripper`).

Frames (docs/sim.md has a drawing). The gripper frame is the flange frame (UR tool0: z out of the flange).

- Parallel jaw: the fingers close along the flange y axis, symmetrically about the flange z axis; the `tcp`
  is the centre between the two pad faces, `T_flange_tcp` = translation (0, 0, 0.145) m; the approach
  direction is tcp +z, the closing direction tcp +-y. Opening 0 to 85 mm (each finger 0 to 42.5 mm).
- Suction: one cup on the flange z axis; the `tcp` is the centre of the cup face, `T_flange_tcp` =
  translation (0, 0, 0.10) m, tcp +z points out of the cup face into the object.

Reliable grasps in MuJoCo (facts from MuJoCo's documentation and users): elliptic friction cones with
`impratio` >= 10 (set by `SceneBuilder`), box-primitive pads with `condim` 6 (sliding, torsional and rolling
friction; small torsional coefficient), pad contacts with priority over the object's so the pad's friction and
stiffer `solref` apply, a few `noslip` iterations (set by `add_robot`) to remove the creep of soft contacts,
and fingers on slide joints driven by actuators (never children of a mocap body, which MuJoCo users report
zeroes the grip friction). The two finger joints are coupled by an equality (q_left = q_right, like the
2F-85 linkage), so a held object cannot slide sideways with both fingers under lateral acceleration.

The fingers are position servos with a force limit, driven like a Robotiq gripper (position, speed, force):
`close(force)` moves the finger targets inwards at `close_speed_m_s` and then past the closed position, so
each finger pushes an object with exactly the force limit `force`; `open()` moves them out to the full
stroke. (A pure force mode with a speed-limiting damper of ~600 N s/m made the pads chatter under the
implicit integrator and let a held box creep down ~1 mm/s; moderate servo damping does not.)

The suction cup holds an object with an equality weld, switched on by `close()` only when the cup face is
in contact with a face of the object (contact normal within `max_face_angle_deg` of the cup axis), and
switched off when the pull on it exceeds the holding force (at most `max_force_n`), when the shear exceeds
the lip friction, or by `open()`.
"""

from __future__ import annotations

import abc
import logging
import math

import mujoco
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import quat_wxyz_from_R

# The geometry lives in the library (one source of truth for planning and simulation); sim builds from it.
from prompose_grasp.grasp.grippers import GRIPPER_TCP, ParallelJawGeometry, SuctionCupGeometry
from prompose_grasp.robot.interfaces import Gripper

__all__ = [
    "GRIPPER_TCP",
    "ParallelJawGeometry",
    "ParallelJawGripper",
    "SuctionCupGeometry",
    "SuctionGripper",
    "add_parallel_jaw",
    "add_suction_cup",
    "add_suction_welds",
]

log = logging.getLogger(__name__)

#: Geom group of gripper geoms (the arm uses group 1 as well: visible by default, distinct from objects).
GROUP_ROBOT = 1
#: contype/conaffinity of robot geoms: they touch the scene (contype 1 = conaffinity 1) but not each other.
ROBOT_CONTYPE, ROBOT_CONAFFINITY = 2, 1

_PAD_FRICTION = (1.0, 0.005, 0.0001)  # sliding [-], torsional [m], rolling [m]: small spin/roll resistance
_PAD_SOLREF = (0.004, 1.0)  # stiffest time constant MuJoCo allows at a 2 ms step (2 x timestep), damped
# Impedance 0.95 at first touch (a rubber pad gives: a 15 g box pinched at 60 N reads 1.0 mm narrow) rising
# to 0.999 at 1 mm deep (the finger behind it does not). MuJoCo scales a soft contact's stiffness by the
# effective mass, so on a light object it is soft in newtons: with 0.99 at depth a 50 g mug's 5.5 mm wall
# slipped out from between the pads at 60 N (tabletop seed 300). 0.99 from first touch held that but let a
# 16 g cup squeeze out of the pinch on the lift (seeds 235, 302): the rigid flat pad then touches a curved
# wall on lines only.
_PAD_SOLIMP = (0.95, 0.999, 0.001, 0.5, 2.0)
#: The finger joints' end stops: metal, stiff from the first touch.
_STOP_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
_FINGER_KP = 2000.0  # [N/m] finger servo stiffness
# [N s/m] finger servo damping: overdamped (critical is 28 for 0.1 kg incl. armature). Much more (~600) makes
# the pads chatter against a held object under the implicit integrator, and the object creeps down.
_FINGER_KV = 100.0
_OPEN_FORCE_N = 100.0  # force limit while opening [N]
#: A finger standing still with its target this far ahead has stalled on something [m]: a finger moving at
#: the 0.1 m/s closing speed trails its target by v kv / kp = 5 mm, and 5 mm of servo error is 10 N.
_STALL_LAG_M = 0.005


def _robot_geom(body, name: str, **kwargs):
    g = body.add_geom(name=name, **kwargs)
    g.group = GROUP_ROBOT
    g.contype = ROBOT_CONTYPE
    g.conaffinity = ROBOT_CONAFFINITY
    return g


# ------------------------------------------------------------------------------------------------------------
# building


def add_parallel_jaw(
    spec: mujoco.MjSpec, flange: mujoco.MjsBody, geometry: ParallelJawGeometry | None = None
) -> np.ndarray:
    """Add the parallel-jaw gripper under `flange`; returns its T_flange_tcp (4, 4).

    Bodies `gripper_base`, `finger_left` (+y), `finger_right` (-y); slide joints `finger_left_joint`,
    `finger_right_joint` (0 closed .. stroke/2 open, the pad face's distance from the centre plane [m]);
    actuators of the same names (force limit `max_force_n`); pad geoms `pad_left`, `pad_right`.
    """
    g = geometry or ParallelJawGeometry()
    base = flange.add_body(name="gripper_base")
    base.mass = g.housing_mass_kg
    base.ipos = [0.0, 0.0, g.palm_z_m / 2.0]
    hx, hy, hz = g.housing_half_m
    base.inertia = [m * g.housing_mass_kg / 3.0 for m in (hy**2 + hz**2, hx**2 + hz**2, hx**2 + hy**2)]
    base.explicitinertial = True
    ch = g.coupling_height_m / 2.0
    _robot_geom(base, "gripper_coupling", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[g.coupling_radius_m, ch, 0], pos=[0, 0, ch], rgba=[0.15, 0.15, 0.15, 1])  # fmt: skip
    _robot_geom(base, "gripper_housing", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(g.housing_half_m),
                pos=[0, 0, g.palm_z_m - hz], rgba=[0.2, 0.2, 0.22, 1])  # fmt: skip
    half_stroke = g.stroke_m / 2.0
    pw, pt, pl = g.pad_size_m
    finger_t = g.finger_thickness_m  # finger plate thickness behind the pad [m]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # Body frame: on the centre plane at the palm; the joint moves it along sign*y so the pad's inner
        # face sits at y = sign * q.
        finger = base.add_body(name=f"finger_{side}", pos=[0.0, 0.0, g.palm_z_m])
        finger.mass = g.finger_mass_kg
        finger.ipos = [0.0, sign * (pt + finger_t / 2.0), g.finger_length_m / 2.0]
        finger.inertia = [g.finger_mass_kg * g.finger_length_m**2 / 12.0] * 3
        finger.explicitinertial = True
        joint = finger.add_joint(
            name=f"finger_{side}_joint",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[0.0, sign, 0.0],
            range=[0.0, half_stroke],
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            armature=0.02,  # reflected inertia of the drive [kg]; also keeps the stiff loop stable at 2 ms
            damping=1.0,
        )
        # A hard stop at closed (and at open): MuJoCo's default limit (time constant 20 ms, impedance
        # 0.9-0.95) let a finger pushing with 60 N sink 10 mm past 0, so jaws closed on nothing read -20 mm
        # (a 2F-85 stops at 0). The pads' time constant and impedance: 0.2 mm past 0 at 60 N.
        joint.solref_limit = list(_PAD_SOLREF)
        joint.solimp_limit = list(_STOP_SOLIMP)
        _robot_geom(finger, f"finger_{side}_plate", type=mujoco.mjtGeom.mjGEOM_BOX,
                    size=[pw / 2.0 + g.finger_width_margin_m, finger_t / 2.0, g.finger_length_m / 2.0],
                    pos=[0.0, sign * (pt + finger_t / 2.0), g.finger_length_m / 2.0],
                    rgba=[0.55, 0.55, 0.58, 1])  # fmt: skip
        pad = _robot_geom(finger, f"pad_{side}", type=mujoco.mjtGeom.mjGEOM_BOX,
                          size=[pw / 2.0, pt / 2.0, pl / 2.0],
                          pos=[0.0, sign * pt / 2.0, g.finger_length_m - pl / 2.0],
                          rgba=[0.1, 0.1, 0.1, 1])  # fmt: skip
        pad.condim = 6
        pad.friction = list(_PAD_FRICTION)
        pad.priority = 1
        pad.solref = list(_PAD_SOLREF)
        pad.solimp = list(_PAD_SOLIMP)
        spec.add_actuator(
            name=f"finger_{side}_joint",
            target=f"finger_{side}_joint",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            gaintype=mujoco.mjtGain.mjGAIN_FIXED,
            biastype=mujoco.mjtBias.mjBIAS_AFFINE,
            gainprm=[_FINGER_KP] + [0.0] * 9,
            biasprm=[0.0, -_FINGER_KP, -_FINGER_KV] + [0.0] * 7,
            forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            forcerange=[-_OPEN_FORCE_N, _OPEN_FORCE_N],
        )
    # The fingers are coupled (q_left = q_right) like the 2F-85's linkage: the pair cannot slide sideways
    # together, so a held object stays centred under lateral acceleration; an off-centre object is centred.
    eq = spec.add_equality(
        name="finger_coupling",
        type=mujoco.mjtEq.mjEQ_JOINT,
        objtype=mujoco.mjtObj.mjOBJ_JOINT,
        name1="finger_left_joint",
        name2="finger_right_joint",
    )
    eq.data = [0.0, 1.0] + [0.0] * 10  # q_left = 0 + 1 * q_right (polynomial coefficients)
    eq.solref = list(_PAD_SOLREF)
    return g.T_flange_tcp


def add_suction_cup(
    spec: mujoco.MjSpec, flange: mujoco.MjsBody, geometry: SuctionCupGeometry | None = None
) -> np.ndarray:
    """Add the suction gripper under `flange`; returns its T_flange_tcp (4, 4).

    Body `suction_cup` (frame = the cup face centre, z out of the face); geom `suction_cup_face` (the lip, a
    cylinder: the cup seals when it is in contact with an object's face). Welds to objects are added by
    `add_suction_welds` once the objects are known (at `SceneBuilder.build`).
    """
    g = geometry or SuctionCupGeometry()
    cup = flange.add_body(name="suction_cup", pos=[0.0, 0.0, g.tcp_z_m])
    cup.mass = g.mass_kg
    cup.ipos = [0.0, 0.0, -g.tcp_z_m / 2.0]
    cup.inertia = [g.mass_kg * g.tcp_z_m**2 / 12.0] * 2 + [g.mass_kg * g.cup_radius_m**2 / 2.0]
    cup.explicitinertial = True
    bh = g.body_height_m / 2.0
    _robot_geom(cup, "suction_body", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[g.body_radius_m, bh, 0],
                pos=[0, 0, -g.tcp_z_m + bh], rgba=[0.2, 0.2, 0.22, 1])  # fmt: skip
    _robot_geom(cup, "suction_stem", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[g.stem_radius_m, (g.stem_length_m - g.body_height_m) / 2.0, 0],
                pos=[0, 0, -g.cup_height_m - (g.stem_length_m - g.body_height_m) / 2.0],
                rgba=[0.6, 0.6, 0.62, 1])  # fmt: skip
    face = _robot_geom(cup, "suction_cup_face", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                       size=[g.cup_radius_m, g.cup_height_m / 2.0, 0], pos=[0, 0, -g.cup_height_m / 2.0],
                       rgba=[0.15, 0.35, 0.75, 1])  # fmt: skip
    face.priority = 1
    face.friction = [1.0, 0.005, 0.0001]
    face.condim = 4
    return g.T_flange_tcp


def add_suction_welds(spec: mujoco.MjSpec, object_bodies: list[str]) -> None:
    """One inactive weld `suction_weld_<body>` between the cup and each free object body."""
    for body in object_bodies:
        eq = spec.add_equality(
            name=f"suction_weld_{body}",
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1="suction_cup",
            name2=body,
        )
        eq.active = False
        # Stiff (time constant 2 x the 2 ms step), critically damped: the held object barely sags.
        eq.solref = [0.004, 1.0]
        eq.solimp = [0.95, 0.99, 0.001, 0.5, 2.0]


# ------------------------------------------------------------------------------------------------------------
# devices


class _SimGripperBase(Gripper):
    """Shared connect/step plumbing of the simulated grippers."""

    kind = ""

    def __init__(self, world):
        robot = getattr(world, "robot", None)
        if robot is None or robot.gripper != self.kind:
            have = None if robot is None else robot.gripper
            raise InvalidInputError(
                f"{type(self).__name__} needs a world built with a {self.kind!r} gripper; it has {have!r}"
            )
        self.world = world

    @abc.abstractmethod
    def command(self) -> tuple[float, float]:
        """What the gripper is told now: (command, force limit [N]); the command is the jaw's target opening
        [m] for a parallel jaw (below 0 while squeezing: the fingers are driven past closed), 1.0 / 0.0 for a
        suction cup's vacuum on / off. Recorded as the action of an episode (`sim.recording`)."""

    @abc.abstractmethod
    def apply_command(self, command: float, force_n: float) -> None:
        """Set what `command()` reads without stepping the world (a recorded action being replayed)."""

    def _step_until(self, done, max_time_s: float, check_every: int = 5) -> bool:
        """Step the world until `done()` is true (checked every few steps) or `max_time_s` passed."""
        dt = self.world.model.opt.timestep
        steps = 0
        while steps * dt < max_time_s:
            self.world.step(check_every)
            steps += check_every
            if done():
                return True
        return False


class ParallelJawGripper(_SimGripperBase):
    """The simulated parallel-jaw gripper of a world built with `gripper="parallel_jaw"`.

    `close(force)` moves both fingers inwards at the closing speed and blocks until they stop; each then
    pushes with `force` [N]. `open()` moves them to the full stroke, `open_to(width_m)` part way. All step
    the shared world (the arm holds its position meanwhile).
    """

    kind = "parallel_jaw"

    def __init__(self, world, geometry: ParallelJawGeometry | None = None):
        super().__init__(world)
        self.geometry = geometry or ParallelJawGeometry()
        m = world.model
        self._act = np.array([m.actuator(f"finger_{s}_joint").id for s in ("left", "right")])
        joints = [m.joint(f"finger_{s}_joint") for s in ("left", "right")]
        self._qadr = np.array([m.jnt_qposadr[j.id] for j in joints])
        self._vadr = np.array([m.jnt_dofadr[j.id] for j in joints])
        self._pads = {m.geom("pad_left").id, m.geom("pad_right").id}
        self._pad_left, self._pad_right = m.geom("pad_left").id, m.geom("pad_right").id
        gripper_bodies = [m.body(n).id for n in ("gripper_base", "finger_left", "finger_right")]
        self._gripper_bodies = set(gripper_bodies)

    def _drive(self, q_final: float, force_n: float) -> None:
        """Ramp both finger targets from where they are to `q_final` at the closing speed, with force limit
        `force_n` [N]; step until the fingers stop.

        The target moves at the closing speed all the way (a 2F-85 closes at its set speed until it meets
        the object): a target that jumped ahead would slam the pads into the object at the full force (the
        pads then hit a paper cup's 2 mm wall at ~1 m/s and went through it). The ramp ends early once both
        fingers have stalled against something (still, with the target `_STALL_LAG_M` ahead): the target
        then goes to `q_final` at once, and the stalled pads push with `force_n` without any impact."""
        m, d = self.world.model, self.world.data
        m.actuator_forcerange[self._act] = [-force_n, force_n]
        start = d.ctrl[self._act].copy()
        step_m = self.geometry.close_speed_m_s * m.opt.timestep
        n = int(np.ceil(np.max(np.abs(q_final - start)) / step_m))
        for k in range(1, n + 1):
            d.ctrl[self._act] = start + np.clip(q_final - start, -k * step_m, k * step_m)
            self.world.step(1)
            if k % 5 == 0 and self._fingers_still():
                past = np.abs(d.ctrl[self._act] - self.world.data.qpos[self._qadr])
                if np.all(past >= min(force_n / _FINGER_KP, _STALL_LAG_M)):
                    break
        d.ctrl[self._act] = q_final
        self.world.step(10)
        self._step_until(self._fingers_still, 1.0)

    def command(self) -> tuple[float, float]:
        d, m = self.world.data, self.world.model
        return float(np.sum(d.ctrl[self._act])), float(m.actuator_forcerange[self._act[0], 1])

    def apply_command(self, command: float, force_n: float) -> None:
        self.world.model.actuator_forcerange[self._act] = [-float(force_n), float(force_n)]
        self.world.data.ctrl[self._act] = float(command) / 2.0  # each finger moves half the opening

    def _fingers_still(self) -> bool:
        return bool(np.all(np.abs(self.world.data.qvel[self._vadr]) < 1e-3))  # 1 mm/s: stopped

    def open(self) -> None:
        self._require()
        half = self.geometry.stroke_m / 2.0
        self._drive(half, _OPEN_FORCE_N)

    def open_to(self, width_m: float) -> None:
        """Open (or close, with the opening force) to a pad-face distance of `width_m` [m], within the stroke:
        a hand opened only as wide as a grasp needs fits between close neighbours."""
        self._require()
        w = float(width_m)
        if not (math.isfinite(w) and 0.0 <= w <= self.geometry.stroke_m + 1e-9):
            stroke = self.geometry.stroke_m
            raise InvalidInputError(f"opening must be within [0, {stroke}] m, got {width_m!r}")
        self._drive(w / 2.0, _OPEN_FORCE_N)

    def close(self, force: float) -> bool:
        self._require()
        g = self.geometry
        if not (math.isfinite(force) and g.min_force_n <= force <= g.max_force_n):
            raise InvalidInputError(
                f"grip force must be within [{g.min_force_n}, {g.max_force_n}] N, got {force!r}"
            )
        # Past the closed position by more than force / kp: a finger stopped anywhere by an object pushes
        # with the saturated servo force, i.e. exactly `force`.
        self._drive(-(float(force) / _FINGER_KP + 0.005), float(force))
        return self.grasp_detected()

    def _pad_contacts(self) -> dict[int, set[int]]:
        """Bodies (not the gripper's) each pad touches now: {pad geom id: {body ids}}."""
        m, d = self.world.model, self.world.data
        out: dict[int, set[int]] = {self._pad_left: set(), self._pad_right: set()}
        for c in d.contact[: d.ncon]:
            for pad, other in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                if pad in out and c.dist <= 1e-4:  # touching (0.1 mm covers contact softness sign noise)
                    body = int(m.geom_bodyid[other])
                    if body not in self._gripper_bodies:
                        out[pad].add(body)
        return out

    def held_body(self) -> int | None:
        """Id of the body squeezed between both pads, or None."""
        contacts = self._pad_contacts()
        common = contacts[self._pad_left] & contacts[self._pad_right]
        return min(common) if common else None

    def grasp_detected(self) -> bool:
        """True when both pads touch the same body with the jaws not fully closed."""
        self._require()
        return self.width() > 1e-3 and self.held_body() is not None  # 1 mm: fingers closed on nothing

    def width(self) -> float:
        """Distance between the pad faces [m] (0 closed, 0.085 open)."""
        self._require()
        return float(np.sum(self.world.data.qpos[self._qadr]))


class SuctionGripper(_SimGripperBase):
    """The simulated suction cup of a world built with `gripper="suction"`.

    `close(force)` switches the vacuum on: when the cup face is in contact with a face of a free object
    (contact normal within `max_face_angle_deg` of the cup axis) the weld to that object is activated;
    otherwise nothing is held. `force` [N] is the holding force asked for, capped by the cup's `max_force_n`.
    While holding, every physics step checks the weld's load and releases the object when the pull along the
    cup axis exceeds the holding force, or the shear exceeds `lip_friction` x (holding force - pull).
    Moments are not limited.
    """

    kind = "suction"

    def __init__(self, world, geometry: SuctionCupGeometry | None = None):
        super().__init__(world)
        self.geometry = geometry or SuctionCupGeometry()
        m = world.model
        self._cup_body = m.body("suction_cup").id
        self._face = m.geom("suction_cup_face").id
        self._face_collision = (int(m.geom_contype[self._face]), int(m.geom_conaffinity[self._face]))
        self._welds: dict[int, int] = {}
        for e in range(m.neq):
            name = m.equality(e).name
            if name.startswith("suction_weld_"):
                self._welds[int(m.eq_obj2id[e])] = e
        self._held_eq: int | None = None
        self._limit_n = self.geometry.max_force_n
        self._vacuum = False  # the vacuum is switched on (whether or not it holds anything)

    def _touching_face_body(self) -> int | None:
        """A free object whose face the cup face touches (normal within the angle limit), or None."""
        m, d = self.world.model, self.world.data
        axis = d.xmat[self._cup_body].reshape(3, 3)[:, 2]
        cos_max = math.cos(math.radians(self.geometry.max_face_angle_deg))
        for c in d.contact[: d.ncon]:
            if self._face not in (c.geom1, c.geom2):
                continue
            other = c.geom2 if c.geom1 == self._face else c.geom1
            body = int(m.geom_bodyid[other])
            if body in self._welds and abs(c.frame[:3] @ axis) >= cos_max:
                return body
        return None

    def open(self) -> None:
        self._require()
        self._release("open()")
        self._vacuum = False
        self.world.step(25)  # 50 ms: the vacuum vents

    def close(self, force: float) -> bool:
        self._require()
        if not (math.isfinite(force) and force > 0):
            raise InvalidInputError(f"holding force must be finite and > 0 N, got {force!r}")
        self._switch_on(float(force))
        self.world.step(25)  # 50 ms: the vacuum builds up (and the load check sees the first steps)
        return self.grasp_detected()

    def _switch_on(self, force_n: float) -> None:
        """Vacuum on with holding force `force_n` [N]: hold the face the cup touches now, if any."""
        self._limit_n = min(force_n, self.geometry.max_force_n)
        self._vacuum = True
        self.world.forward()
        body = self._touching_face_body()
        if body is not None and self._held_eq is None:
            self._attach(body)

    def command(self) -> tuple[float, float]:
        return (1.0 if self._vacuum else 0.0), float(self._limit_n)

    def apply_command(self, command: float, force_n: float) -> None:
        on = float(command) >= 0.5
        if on and not self._vacuum:
            self._switch_on(float(force_n))
        elif not on and self._vacuum:
            self._release("vacuum off")
            self._vacuum = False

    def _attach(self, body: int) -> None:
        m, d = self.world.model, self.world.data
        eq = self._welds[body]
        # Weld point: the cup face centre (the cup body origin), fixed on the object where it is now; the
        # relative orientation is the current one, so nothing jumps. The load is then measured at the cup.
        R1, p1 = d.xmat[self._cup_body].reshape(3, 3), d.xpos[self._cup_body]
        R2, p2 = d.xmat[body].reshape(3, 3), d.xpos[body]
        m.eq_data[eq, 0:3] = R2.T @ (p1 - p2)  # anchor: the cup point in the object frame
        m.eq_data[eq, 3:6] = 0.0  # ... which is the cup body origin
        m.eq_data[eq, 6:10] = quat_wxyz_from_R(R1.T @ R2)
        m.eq_data[eq, 10] = 1.0  # torquescale: rotational rows carry torques [N m]
        # The weld carries the object; the face contact would fight it (the cup pressed in a little), so
        # the face stops colliding while it holds.
        m.geom_contype[self._face] = 0
        m.geom_conaffinity[self._face] = 0
        d.eq_active[eq] = 1
        self._held_eq = eq
        self.world.add_step_hook(self._check_load)  # only while holding: stepping is faster without hooks
        log.debug("suction: holding body %d", body)

    def _release(self, why: str) -> None:
        if self._held_eq is not None:
            self.world.data.eq_active[self._held_eq] = 0
            log.debug("suction: released (%s)", why)
        m = self.world.model
        m.geom_contype[self._face], m.geom_conaffinity[self._face] = self._face_collision
        self.world.remove_step_hook(self._check_load)
        self._held_eq = None

    def _check_load(self, world) -> None:
        eq = self._held_eq
        if eq is None:
            return
        d = world.data
        if not d.eq_active[eq]:  # reset or switched off elsewhere
            self._release("weld switched off")
            return
        rows = np.flatnonzero((d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (d.efc_id == eq))
        if rows.size < 6:
            return
        # The translational rows are world-frame forces (minus the force on the object). A vacuum cup lets go
        # when the pull along its axis exceeds the holding force, or when the shear exceeds the lip's friction
        # under the net pressing force (holding force minus pull; pressing the cup on adds to it).
        f_rows = d.efc_force[rows[:3]]
        axis = d.xmat[self._cup_body].reshape(3, 3)[:, 2]
        tension = float(f_rows @ axis)
        shear = float(np.linalg.norm(f_rows - tension * axis))
        if tension > self._limit_n or shear > self.geometry.lip_friction * (self._limit_n - tension):
            log.info(
                "suction: pull %.1f N / shear %.1f N exceed the holding force %.1f N; the object drops",
                tension, shear, self._limit_n,
            )  # fmt: skip
            self._release("overload")

    def held_body(self) -> int | None:
        """Id of the body held by the vacuum, or None."""
        return None if self._held_eq is None else int(self.world.model.eq_obj2id[self._held_eq])

    def grasp_detected(self) -> bool:
        self._require()
        return self._held_eq is not None and bool(self.world.data.eq_active[self._held_eq])

    def width(self) -> float:
        """Always 0 (a suction cup has no opening)."""
        self._require()
        return 0.0
