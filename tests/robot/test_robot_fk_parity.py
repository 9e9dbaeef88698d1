"""FK parity: closed-form DH vs Pinocchio (from the URDF) vs MuJoCo (MjSpec from the same URDF); Jacobian."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from prompose_grasp.geometry.se3 import make_T, random_rotation, so3_log
from prompose_grasp.robot import add_arm_to_spec, known_robots, load_robot, ur_urdf
from prompose_grasp.robot.kinematics import fk_batch, rotation_distance

# The parity bound; float64 chains of 6 transforms agree to ~1e-15, so 1e-9 leaves ample margin.
PARITY_TOL = 1e-9
TCP_OFFSET = np.array([0.01, -0.02, 0.16])


def _pose_gap(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), float(rotation_distance(A[:3, :3], B[:3, :3]))


@pytest.mark.parametrize("name", known_robots())
def test_closed_form_pinocchio_mujoco_agree(name):
    robot = load_robot(name, tcp_offset=TCP_OFFSET)
    rng = np.random.default_rng(7)
    for q in robot.random_configurations(rng, 25):
        for frame in ("flange", "tcp"):
            T_dh = robot.fk_frame(q, frame)
            for T_other in (robot.fk_pinocchio(q, frame), robot.fk_mujoco(q, frame)):
                pos, rot = _pose_gap(T_dh, T_other)
                assert pos <= PARITY_TOL and rot <= PARITY_TOL, (name, frame, q, pos, rot)


def test_tcp_is_flange_times_offset():
    robot = load_robot("ur5e", tcp_offset=TCP_OFFSET)
    q = np.array([0.3, -1.2, 1.1, -0.4, 1.3, 0.2])
    T_flange = robot.fk(q)
    np.testing.assert_allclose(
        robot.fk_tcp(q)[:3, 3], T_flange[:3, :3] @ TCP_OFFSET + T_flange[:3, 3], atol=1e-15
    )
    # A UR pose vector (x, y, z, rx, ry, rz) works as the offset too; rotation about z by pi/2 here.
    robot6 = load_robot("ur5e", tcp_offset=[0, 0, 0.1, 0, 0, np.pi / 2])
    np.testing.assert_allclose(robot6.fk_tcp(q)[:3, 0], T_flange[:3, 1], atol=1e-12)  # float64 rounding


def test_batch_fk_matches_single():
    robot = load_robot("ur10e")
    Q = robot.random_configurations(np.random.default_rng(1), 10)
    np.testing.assert_allclose(fk_batch(robot.spec, Q), np.stack([robot.fk(q) for q in Q]), atol=1e-14)


@pytest.mark.parametrize("name", ["ur5e", "ur3e"])
def test_mujoco_capsules_match_the_urdf_capsules(name):
    robot = load_robot(name)
    model = robot.mj_model
    data = mujoco.MjData(model)
    q = robot.random_configurations(np.random.default_rng(2), 1)[0]
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    capsules = robot.capsules_in_base(q)
    assert model.ngeom == len(capsules) == 7
    for k, (link, p0, p1, radius) in enumerate(capsules):
        gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{link}_capsule0")
        assert gid == k and model.geom_type[gid] == mujoco.mjtGeom.mjGEOM_CAPSULE
        centre, axis = data.geom_xpos[gid], data.geom_xmat[gid].reshape(3, 3)[:, 2]
        half = model.geom_size[gid, 1]
        ends = sorted([centre - half * axis, centre + half * axis], key=lambda p: np.linalg.norm(p - p0))
        np.testing.assert_allclose(ends[0], p0, atol=1e-12)  # float64 rounding through quaternions
        np.testing.assert_allclose(ends[1], p1, atol=1e-12)
        assert model.geom_size[gid, 0] == pytest.approx(radius)


def test_arm_added_to_a_scene_at_a_base_pose():
    robot = load_robot("ur5e", tcp_offset=TCP_OFFSET)
    T_world_base = make_T(random_rotation(np.random.default_rng(4)), [0.4, -0.2, 0.75])
    scene = mujoco.MjSpec()
    scene.compiler.degree = True  # MJCF's default angle unit; joint ranges must still come out in radians
    add_arm_to_spec(scene, ur_urdf(robot.spec), T_world_base, prefix="left_", T_flange_tcp=robot.T_flange_tcp,
                    actuator_kp=2000.0)  # fmt: skip
    model = scene.compile()
    assert model.nu == 6
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "left_elbow_joint")
    np.testing.assert_allclose(model.jnt_range[jid], [-np.pi, np.pi], atol=1e-12)  # float64 rounding
    data = mujoco.MjData(model)
    q = np.array([0.5, -1.0, 1.4, -0.7, -1.5, 0.3])
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    for site, T_base_site in (("left_flange", robot.fk(q)), ("left_tcp", robot.fk_tcp(q))):
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
        T_mj = make_T(data.site_xmat[sid].reshape(3, 3), data.site_xpos[sid])
        pos, rot = _pose_gap(T_mj, T_world_base @ T_base_site)
        assert pos <= PARITY_TOL and rot <= PARITY_TOL


@pytest.mark.parametrize("name", ["ur5e", "ur16e"])
def test_jacobian_matches_finite_differences(name):
    robot = load_robot(name, tcp_offset=TCP_OFFSET)
    rng = np.random.default_rng(5)
    h = 1e-6
    for q in robot.random_configurations(rng, 5):
        for frame in ("flange", "tcp"):
            J = robot.jacobian(q, frame)
            J_fd = np.empty((6, 6))
            for j in range(6):
                dq = np.zeros(6)
                dq[j] = h
                Tp, Tm = robot.fk_frame(q + dq, frame), robot.fk_frame(q - dq, frame)
                J_fd[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
                J_fd[3:, j] = so3_log(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
            # Central differences, h = 1e-6 on ~1 m lever arms: truncation ~h^2, rounding ~1e-16/h = 1e-10.
            np.testing.assert_allclose(J, J_fd, atol=1e-8)
