"""SimArm: FK parity with the robot layer, validation before any motion, straight lines, stop, scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnreachableError, UnsafeCommandError
from prompose_grasp.geometry.se3 import invert_T, make_T, rotation_angle
from prompose_grasp.robot import CommandValidator, JointTrajectory, RGBDFrame, ValidatorConfig
from prompose_grasp.robot.fake import HOME_Q
from sim.arm import SimArm, trapezoid_profile
from sim.camera import CameraSpec, SimCamera
from sim.robot_scene import add_robot
from sim.scene_builder import SceneBuilder
from sim.scene_file import build_scene, load_scene

pytestmark = pytest.mark.sim

SCENES = sorted((Path(__file__).parents[2] / "sim" / "scenes").glob("*.yaml"))
#: Base yawed -90 deg: the home pose (TCP along base -x) reaches over the table towards world +y.
T_WORLD_BASE = make_T(np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.0, -0.55, 0.75])
R_DOWN = np.diag([1.0, -1.0, -1.0])  # tcp z pointing down in base (base z up)


def _world(gripper="parallel_jaw", robot="ur5e"):
    b = SceneBuilder("arm")
    b.add_floor()
    b.add_table()
    add_robot(b, robot, T_WORLD_BASE, gripper=gripper)
    b.add_camera(
        CameraSpec("wrist", 64, 48, 60.0, make_T(np.eye(3), [0.0, 0.07, 0.03]), parent_body="flange")
    )
    return b.build()


def _state(world):
    d = world.data
    return [a.copy() for a in (d.qpos, d.qvel, d.ctrl, d.qfrc_applied)] + [float(d.time)]


def test_trapezoid_profile_reaches_length_with_bounded_speed_and_accel():
    t = np.linspace(0.0, 3.0, 3001)
    s, v, a, duration = trapezoid_profile(0.6, 1.0, 3.0, t)
    assert s[-1] == pytest.approx(0.6) and v[-1] == 0.0
    assert v.max() == pytest.approx(1.0)  # long enough to cruise
    assert np.abs(a).max() == pytest.approx(3.0)
    # s is the integral of v: trapezoid rule error for this grid is far below 1e-6 m
    np.testing.assert_allclose(
        s, np.concatenate([[0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]), atol=1e-6
    )
    assert duration == pytest.approx(0.6 / 1.0 + 1.0 / 3.0)  # cruise time + one ramp
    s, v, _, duration = trapezoid_profile(0.01, 1.0, 3.0, t)  # too short to cruise: a triangle
    assert duration == pytest.approx(2 * np.sqrt(0.01 / 3.0)) and v.max() < 1.0


def test_tcp_pose_matches_robot_fk():
    """The sim's flange pose is the robot layer's closed-form FK; the servo reaches commanded q to < 1 mm."""
    with _world() as world, SimArm(world) as arm:
        robot = arm.robot
        np.testing.assert_allclose(arm.joint_positions(), HOME_Q, atol=1e-12)
        rng = np.random.default_rng(0)
        for _ in range(3):
            q = HOME_Q + rng.uniform(-0.4, 0.4, 6)
            command = arm.move_joints(q, 1.0, 3.0)
            T_sim = arm.tcp_pose()
            # Same URDF for MuJoCo and the DH table: identical up to float rounding (1e-9 m).
            np.testing.assert_allclose(T_sim, robot.fk_tcp(arm.joint_positions()), atol=1e-9)
            # Servo residual after settling with gravity compensated: below 1 mm / 2 mrad at the TCP
            # (stiffness 30 N m/rad per N m of torque limit against the gripper's unmodelled offsets).
            T_cmd = robot.fk_tcp(command.q)
            assert np.linalg.norm(T_sim[:3, 3] - T_cmd[:3, 3]) < 1e-3
            assert rotation_angle(T_sim[:3, :3], T_cmd[:3, :3]) < 2e-3
        T_world_tcp = world.T_world_base @ arm.tcp_pose()
        # The tcp is 0.145 m along the flange z from the flange (parallel-jaw convention, docs/sim.md).
        np.testing.assert_allclose(
            invert_T(arm.T_world_flange()) @ T_world_tcp, make_T(np.eye(3), [0, 0, 0.145]), atol=1e-9
        )


def test_refused_commands_leave_the_sim_untouched():
    with _world() as world, SimArm(world) as arm:
        before = _state(world)
        _, upper = arm.robot.joint_limits
        bad_q = HOME_Q.copy()
        bad_q[2] = upper[2] + 0.1
        with pytest.raises(UnsafeCommandError, match="elbow_joint"):
            arm.move_joints(bad_q, 1.0, 1.0)
        with pytest.raises(UnsafeCommandError, match="NaN"):
            arm.move_joints(np.full(6, np.nan), 1.0, 1.0)
        with pytest.raises(UnsafeCommandError, match="speed"):
            arm.move_joints(HOME_Q + 0.1, 100.0, 1.0)
        with pytest.raises(UnsafeCommandError, match="workspace"):
            arm.move_linear(make_T(R_DOWN, [0.0, 0.0, 3.0]), 0.1, 0.5)
        with pytest.raises(UnsafeCommandError, match="TCP speed"):
            arm.move_linear(arm.tcp_pose(), 5.0, 0.5)
        too_fast = JointTrajectory(t_s=[0.01], q=[HOME_Q + np.array([0.15, 0, 0, 0, 0, 0])])  # 15 rad/s
        with pytest.raises(UnsafeCommandError, match="speed limit"):
            arm.follow(too_fast)
        # Beyond the UR5e's reach (0.85 m) yet inside the workspace box: IK refuses before anything moves.
        with pytest.raises(UnreachableError):
            arm.move_linear(make_T(R_DOWN, [-1.3, 0.0, 0.2]), 0.2, 0.5)
        # A replayed set-point stream (`servo`) is checked too: limits, NaN, and a jump no speed cap allows.
        zero = np.zeros(6)
        with pytest.raises(UnsafeCommandError, match="elbow_joint"):
            arm.servo(bad_q, zero, zero)
        with pytest.raises(UnsafeCommandError, match="NaN"):
            arm.servo(np.full(6, np.nan), zero, zero)
        with pytest.raises(UnsafeCommandError, match="jumps"):
            jump = np.array([0.05, 0, 0, 0, 0, 0])  # in one 2 ms step: 25 rad/s
            arm.servo(arm.commanded_joint_positions() + jump, zero, zero)
        with pytest.raises(UnsafeCommandError, match="not finite"):
            arm.servo(arm.commanded_joint_positions(), np.full(6, np.inf), zero)
        after = _state(world)
        for a, b in zip(before, after):
            np.testing.assert_array_equal(a, b)


def test_move_linear_follows_a_straight_line():
    with _world() as world, SimArm(world) as arm:
        T0 = arm.tcp_pose()
        T1 = make_T(T0[:3, :3], T0[:3, 3] + [0.10, -0.25, -0.15])
        path = []
        world.add_step_hook(lambda w: path.append(arm.tcp_pose()[:3, 3]))
        command = arm.move_linear(T1, 0.5, 2.0)
        np.testing.assert_array_equal(command.T_base_tcp, T1)
        P = np.array(path)
        d = (T1[:3, 3] - T0[:3, 3]) / np.linalg.norm(T1[:3, 3] - T0[:3, 3])
        off_line = P - T0[:3, 3] - np.outer((P - T0[:3, 3]) @ d, d)
        # 1 mm: servo lag at 0.5 m/s with velocity and inertia feed-forward, plus joint-space interpolation
        # between IK waypoints 16 ms apart.
        assert np.linalg.norm(off_line, axis=1).max() < 1e-3
        assert np.linalg.norm(arm.tcp_pose()[:3, 3] - T1[:3, 3]) < 1e-3  # 1 mm: settled servo residual
        speeds = np.linalg.norm(np.diff(P, axis=0), axis=1) / world.model.opt.timestep
        assert speeds.max() == pytest.approx(0.5, abs=0.03)  # cruises at the commanded speed (3 % servo lag)


def test_follow_and_stop():
    with _world() as world, SimArm(world) as arm:
        t = np.arange(1, 51) * 0.02
        q = HOME_Q + np.outer(0.3 * (1 - np.cos(np.pi * t / t[-1])) / 2, [1, 0.5, -0.5, 0, 0.3, 1])
        sent = arm.follow(JointTrajectory(t_s=t, q=q))
        np.testing.assert_array_equal(sent.q, q)
        assert np.abs(arm.joint_positions() - q[-1]).max() < 2e-3  # 2 mrad: settled servo residual
        # stop() during a long move (called from a step hook, as another thread would): the arm
        # decelerates and stays short of the target.
        start = arm.joint_positions()
        target = start + np.array([1.0, 0, 0, 0, 0, 0])
        t_stop = world.data.time + 0.4
        world.add_step_hook(lambda w: arm.stop() if abs(w.data.time - t_stop) < 1e-9 else None)
        arm.move_joints(target, 1.0, 2.0)
        q_end = arm.joint_positions()
        assert 0.05 < q_end[0] - start[0] < 0.5  # moved, then stopped well before the 1 rad target
        assert np.abs(arm.joint_velocities()).max() < 1e-2  # at rest (settle threshold 2e-3 rad/s + slack)
        assert arm.timing().sim_time_s > 0 and arm.timing().realtime_factor > 0


def test_simarm_needs_a_robot_and_a_matching_model():
    b = SceneBuilder("empty")
    b.add_floor()
    with b.build() as world, pytest.raises(InvalidInputError, match="robot"):
        SimArm(world)
    from prompose_grasp.robot import load_robot

    with _world() as world:
        with pytest.raises(InvalidInputError, match="ur10e"):
            SimArm(world, load_robot("ur10e"))
        custom = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.2])
        config = ValidatorConfig.for_robot(custom, max_tcp_speed_m_s=1.0)
        with SimArm(world, custom, validator=CommandValidator(config, fk_tcp=custom.fk_tcp)) as arm:
            np.testing.assert_allclose(arm.tcp_pose(), custom.fk_tcp(arm.joint_positions()), atol=1e-9)


def test_wrist_camera_follows_the_flange_and_frames_are_in_base():
    with _world() as world, SimArm(world) as arm:
        arm.move_joints(HOME_Q + np.array([0.3, 0.1, -0.2, 0.2, 0.1, 0.5]), 1.0, 3.0)
        T_flange_cam = make_T(np.eye(3), [0.0, 0.07, 0.03])
        with SimCamera(world, "wrist") as cam:
            frame = cam.capture()
        np.testing.assert_allclose(world.T_world_cam("wrist"), arm.T_world_flange() @ T_flange_cam, atol=1e-9)
        assert isinstance(frame, RGBDFrame) and frame.timestamp_s == pytest.approx(world.data.time)
        T_base_cam = arm.robot.fk(arm.joint_positions()) @ T_flange_cam  # independent: DH chain
        np.testing.assert_allclose(frame.T_base_cam, T_base_cam, atol=1e-9)


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scenario_with_robot_steps_finite(path):
    """Every scene builds its robot and gripper, steps 1000 steps, resets, steps again; the arm holds home."""
    spec = load_scene(path)
    with build_scene(spec, settle=False) as world:
        info = world.robot
        assert info is not None and info.name == spec.robot["model"] and info.gripper == spec.gripper["type"]
        for _ in range(2):
            world.step(1000)
            assert world.is_finite()
            # 1 mrad: the servos hold home against gravity (compensated) and nothing touches the arm
            np.testing.assert_allclose(world.data.qpos[info.qpos_adr], info.home_q, atol=1e-3)
            world.reset()
            np.testing.assert_array_equal(world.data.qpos[info.qpos_adr], info.home_q)
        wrist = [c for c in world.cameras.values() if c.parent_body is not None]
        for cam in wrist:  # wrist cameras ride on the arm's flange, not on a stand-in
            assert world.model.body(cam.parent_body).id == info.flange_body
