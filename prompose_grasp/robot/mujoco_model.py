"""MuJoCo models of the UR arms, built with `mujoco.MjSpec` from the generated URDF.

The builder reads the URDF text (through `parse_urdf`) rather than the DH table, so MuJoCo sees exactly what
Pinocchio sees. Bodies are named like the URDF links (`base`, `shoulder_link`, ..., `wrist_3_link`, `flange`),
joints like the UR joints (`shoulder_pan_joint`, ..., `wrist_3_joint`); the `flange` body carries a `flange`
site (DH frame 6, ROS tool0) and, when a TCP offset is given, a `tcp` site. Each link carries its collision
capsule as a MuJoCo capsule geom named `<link>_capsule<k>`, the same segment and radius as in the URDF.

Use `ur_mjspec` for a standalone arm, or `add_arm_to_spec` to put an arm into a scene at a given base pose
(the sim does this and attaches a gripper to the `flange` body).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import as_transform, quat_wxyz_from_R
from prompose_grasp.robot.ur_models import FLANGE_NAME, TCP_NAME, URSpec
from prompose_grasp.robot.urdf import ArmDescription, parse_urdf, rotation_from_rpy, ur_urdf

#: Name of the support-plane geom added by `add_support_plane` (used by mink's collision avoidance).
SUPPORT_PLANE_NAME = "support_plane"


def _quat_wxyz_from_rpy(rpy: tuple[float, float, float]) -> np.ndarray:
    return quat_wxyz_from_R(rotation_from_rpy(rpy))


def add_arm_to_spec(
    spec: mujoco.MjSpec,
    urdf_text: str,
    T_parent_base: ArrayLike | None = None,
    parent_body: mujoco.MjsBody | None = None,
    prefix: str = "",
    T_flange_tcp: ArrayLike | None = None,
    actuator_kp: float | None = None,
) -> mujoco.MjsBody:
    """Add an arm described by `urdf_text` to `spec` under `parent_body` (default: the world body).

    Args:
        spec: the scene being built; its angle unit (`spec.compiler.degree`) is respected.
        urdf_text: URDF of a serial arm as written by `prompose_grasp.robot.urdf` (e.g. `ur_urdf(spec)`).
        T_parent_base: (4, 4) pose of the arm's `base` in the parent body's frame [m]; identity if None.
        parent_body: body to attach to; the world body if None.
        prefix: prepended to every body, joint, geom, site and actuator name (for several arms in one scene).
        T_flange_tcp: (4, 4) TCP offset; adds a `tcp` site on the flange body when given.
        actuator_kp: when given, adds a position actuator per joint with this stiffness [N m / rad],
            force-limited to the joint's torque limit and control-limited to its range.

    Returns:
        The arm's root body (`<prefix>base`).
    """
    desc: ArmDescription = parse_urdf(urdf_text)
    T = np.eye(4) if T_parent_base is None else as_transform(T_parent_base, "T_parent_base")
    parent = spec.worldbody if parent_body is None else parent_body
    to_spec_angle = (180.0 / math.pi) if spec.compiler.degree else 1.0

    bodies: dict[str, mujoco.MjsBody] = {}
    root = parent.add_body(name=prefix + desc.root, pos=T[:3, 3], quat=quat_wxyz_from_R(T[:3, :3]))
    bodies[desc.root] = root
    for joint in desc.joints:
        body = bodies[joint.parent].add_body(
            name=prefix + joint.child, pos=list(joint.xyz), quat=_quat_wxyz_from_rpy(joint.rpy)
        )
        bodies[joint.child] = body
        if joint.type == "revolute":
            body.add_joint(
                name=prefix + joint.name,
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=list(joint.axis),
                range=[joint.lower_rad * to_spec_angle, joint.upper_rad * to_spec_angle],
                limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            )
            if actuator_kp is not None:
                spec.add_actuator(
                    name=prefix + joint.name,
                    target=prefix + joint.name,
                    trntype=mujoco.mjtTrn.mjTRN_JOINT,
                    gaintype=mujoco.mjtGain.mjGAIN_FIXED,
                    biastype=mujoco.mjtBias.mjBIAS_AFFINE,
                    gainprm=[actuator_kp] + [0.0] * 9,
                    biasprm=[0.0, -actuator_kp, 0.0] + [0.0] * 7,
                    ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
                    ctrlrange=[joint.lower_rad, joint.upper_rad],
                    forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
                    forcerange=[-joint.effort_nm, joint.effort_nm],
                )

    for link in desc.links:
        body = bodies[link.name]
        if link.inertial is not None:
            body.mass = link.inertial.mass_kg
            body.ipos = list(link.inertial.com_xyz)
            body.iquat = _quat_wxyz_from_rpy(link.inertial.rpy)
            body.inertia = list(link.inertial.inertia_diag)
            body.explicitinertial = True
        for k, capsule in enumerate(link.capsules):
            body.add_geom(
                name=f"{prefix}{link.name}_capsule{k}",
                type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                fromto=[*capsule.p0, *capsule.p1],
                size=[capsule.radius_m, 0.0, 0.0],
                rgba=[0.6, 0.65, 0.7, 1.0],
            )
    if FLANGE_NAME not in bodies:
        raise InvalidInputError(f"the URDF has no {FLANGE_NAME!r} link; links: {', '.join(bodies)}")
    flange = bodies[FLANGE_NAME]
    flange.add_site(name=prefix + FLANGE_NAME, size=[0.005, 0.0, 0.0])
    if T_flange_tcp is not None:
        T_tcp = as_transform(T_flange_tcp, "T_flange_tcp")
        flange.add_site(
            name=prefix + TCP_NAME,
            pos=T_tcp[:3, 3],
            quat=quat_wxyz_from_R(T_tcp[:3, :3]),
            size=[0.005, 0.0, 0.0],
        )
    return root


def add_support_plane(spec: mujoco.MjSpec, height_m: float = 0.0, name: str = SUPPORT_PLANE_NAME) -> None:
    """Add an infinite horizontal plane geom at z = `height_m` [m] in the world frame (the arm's table)."""
    spec.worldbody.add_geom(
        name=name, type=mujoco.mjtGeom.mjGEOM_PLANE, pos=[0.0, 0.0, float(height_m)], size=[0.0, 0.0, 0.05]
    )


def ur_mjspec(
    spec: URSpec,
    T_flange_tcp: ArrayLike | None = None,
    actuator_kp: float | None = None,
    support_plane_z_m: float | None = None,
) -> mujoco.MjSpec:
    """A standalone MjSpec of a UR arm with `base` at the world origin (radians, no gravity compensation).

    Args:
        spec: the arm (see `get_ur_spec`).
        T_flange_tcp: (4, 4) TCP offset; adds a `tcp` site when given.
        actuator_kp: adds position actuators with this stiffness when given.
        support_plane_z_m: adds a `support_plane` geom at this height in the base frame when given [m].
    """
    mj = mujoco.MjSpec()
    mj.modelname = spec.name
    mj.compiler.degree = False
    add_arm_to_spec(mj, ur_urdf(spec), T_flange_tcp=T_flange_tcp, actuator_kp=actuator_kp)
    if support_plane_z_m is not None:
        add_support_plane(mj, support_plane_z_m)
    return mj
