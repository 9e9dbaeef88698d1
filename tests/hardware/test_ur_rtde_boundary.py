"""URRtdeArm against stand-ins at our own boundary (`RtdeLinks`): the exact ur_rtde calls and their order,
validator refusals that never reach the wire, the stop paths and the typed errors."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from rtde_fakes import CallLog, FakeControl, FakeIO, FakeLinks, FakeReceive

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError, UnsafeCommandError
from prompose_grasp.geometry.se3 import T_from_pose_vector, pose_vector_from_T
from prompose_grasp.hardware import (
    ConnectionLostError,
    EmergencyStopError,
    MotionFailedError,
    ProtectiveStopError,
    URRtdeArm,
    URRtdeConfig,
)
from prompose_grasp.robot import HOME_Q, JointTrajectory, load_robot

TCP_Z_M = 0.145
ROBOT = load_robot("ur5e", tcp_offset=[0.0, 0.0, TCP_Z_M])


def make_arm(moving_polls: int = 3, config: URRtdeConfig | None = None):
    log = CallLog()
    control = FakeControl(log, moving_polls=moving_polls)
    receive = FakeReceive(HOME_Q, pose_vector_from_T(ROBOT.fk_tcp(HOME_Q)))
    control.receive = receive  # the arm arrives where it was sent
    links = FakeLinks(control, receive, FakeIO(log))
    arm = URRtdeArm("10.0.0.2", ROBOT, config=config or URRtdeConfig(poll_period_s=0.001), links=links)
    return arm, control, receive, log, links


def test_connect_opens_receive_then_control_and_sets_the_models_tcp():
    arm, _, _, log, links = make_arm()
    arm.connect()
    assert links.opened == ["receive", "control"]
    assert log.names() == ["setTcp"]
    # The TCP pose vector of a pure translation along flange z: (0, 0, 0.145, 0, 0, 0).
    np.testing.assert_allclose(log[0][1][0], [0, 0, TCP_Z_M, 0, 0, 0], atol=1e-15)  # exact up to rounding
    arm.disconnect()


def test_connect_waits_for_the_state_that_carries_the_new_tcp():
    # RTDE publishes on its own cycle: the first packages after setTcp may still carry the flange pose
    # (the old TCP). connect() returns only once the reported TCP agrees with the model's FK.
    arm, _, receive, _, _ = make_arm()
    receive.tcp_pose = pose_vector_from_T(ROBOT.fk(HOME_Q)).tolist()
    stale_reads = [3]

    real = receive.getActualTCPPose

    def delayed():
        if stale_reads[0] > 0:
            stale_reads[0] -= 1
            return real()
        receive.tcp_pose = pose_vector_from_T(ROBOT.fk_tcp(HOME_Q)).tolist()
        return real()

    receive.getActualTCPPose = delayed
    arm.connect()
    assert stale_reads[0] == 0
    np.testing.assert_allclose(arm.tcp_pose(), ROBOT.fk_tcp(HOME_Q), atol=1e-12)
    arm.disconnect()


def test_connect_refuses_a_controller_whose_tcp_the_model_does_not_explain():
    # A UR10e model on this arm (or a TCP the controller did not take): the reported TCP is metres-scale
    # away from the model's FK at the same joints, so every planned move would be off by as much.
    arm, _, receive, log, _ = make_arm(config=URRtdeConfig(poll_period_s=0.001, tcp_sync_timeout_s=0.05))
    receive.tcp_pose = pose_vector_from_T(
        load_robot("ur10e", tcp_offset=[0, 0, TCP_Z_M]).fk_tcp(HOME_Q)
    ).tolist()
    with pytest.raises(DeviceNotConnectedError, match="from where the ur5e model puts it"):
        arm.connect()
    assert not arm.is_connected and log.names()[-2:] == ["stopScript", "disconnect"]


def test_move_joints_sends_one_async_moveJ_then_polls_until_done():
    arm, _, _, log, _ = make_arm(moving_polls=3)
    with arm:
        q = HOME_Q + np.array([0.1, -0.05, 0.05, 0.0, 0.1, -0.2])
        sent = arm.move_joints(q, 0.5, 1.0)
    assert log.names() == ["setTcp", "moveJ"] + ["getAsyncOperationProgress"] * 4 + [
        "stopScript",
        "disconnect",
    ]
    _, (q_sent, speed, accel, asynchronous) = log[1]
    assert q_sent == q.tolist() and (speed, accel, asynchronous) == (0.5, 1.0, True)
    np.testing.assert_array_equal(sent.q, q)


def test_move_linear_sends_the_ur_pose_vector_of_the_target():
    arm, _, _, log, _ = make_arm(moving_polls=0)
    T = ROBOT.fk_tcp(HOME_Q)
    T[:3, 3] += [0.02, -0.03, -0.05]
    with arm:
        arm.move_linear(T, 0.1, 0.5)
    name, (pose, speed, accel, asynchronous) = log[1]
    assert name == "moveL" and (speed, accel, asynchronous) == (0.1, 0.5, True)
    # Round trip through (x, y, z, rotation vector): float64 rounding only.
    np.testing.assert_allclose(T_from_pose_vector(pose), T, atol=1e-12)
    np.testing.assert_allclose(pose[:3], T[:3, 3], atol=0)  # the translation is copied, not computed


def test_a_move_that_never_runs_nor_arrives_is_stopped_and_reported():
    arm, control, _, log, _ = make_arm(
        moving_polls=0, config=URRtdeConfig(poll_period_s=0.001, start_timeout_s=0.05)
    )
    control.receive = None  # progress reads -1 at once and the arm stays where it was
    with arm:
        with pytest.raises(MotionFailedError, match="never reported the move running"):
            arm.move_joints(HOME_Q + 0.05, 0.5, 1.0)
        assert arm.is_connected  # the link is fine: only the move failed
    names = log.names()
    assert names.index("stopJ") > names.index("moveJ")


def test_tcp_pose_is_the_receive_pose_vector_as_a_transform():
    arm, _, receive, _, _ = make_arm()
    with arm:
        T = arm.tcp_pose()
        q = arm.joint_positions()
    np.testing.assert_array_equal(q, HOME_Q)
    # The fake reports the model's own FK, so the conversion must give it back (float64 rounding).
    np.testing.assert_allclose(T, ROBOT.fk_tcp(HOME_Q), atol=1e-12)
    np.testing.assert_allclose(T, T_from_pose_vector(receive.tcp_pose), atol=0)


def test_follow_streams_servoJ_at_the_controller_rate_then_servoStop():
    rate = 500.0
    arm, _, _, log, _ = make_arm(config=URRtdeConfig(servo_rate_hz=rate, lookahead_s=0.05, gain=500))
    dq = np.array([0.02, -0.02, 0.02, 0.01, -0.01, 0.02])
    traj = JointTrajectory(t_s=np.array([0.1, 0.2, 0.3]), q=HOME_Q + np.outer([1, 2, 3], dq))
    with arm:
        arm.follow(traj)
    names = log.names()
    servo = [args for name, args in log if name == "servoJ"]
    # 0.3 s at 2 ms: samples at 0, 2, ..., 300 ms.
    assert len(servo) == round(0.3 * rate) + 1
    body = names[1 : 1 + 3 * len(servo)]
    assert body == ["initPeriod", "servoJ", "waitPeriod"] * len(servo)
    assert names[1 + 3 * len(servo)] == "servoStop"
    np.testing.assert_allclose(servo[0][0], HOME_Q, atol=0)  # starts where the arm stands
    np.testing.assert_allclose(servo[-1][0], traj.q[-1], atol=1e-15)  # ends on the last waypoint
    assert servo[0][1:] == (0.0, 0.0, 1.0 / rate, 0.05, 500)
    # Linear interpolation: halfway to the first waypoint at 50 ms.
    np.testing.assert_allclose(servo[25][0], HOME_Q + 0.5 * dq, atol=1e-12)


@pytest.mark.parametrize(
    "bad",
    [
        lambda arm: arm.move_joints(
            HOME_Q + np.array([0, 0, 0, 0, 0, 7.0]), 0.5, 1.0
        ),  # beyond the wrist limit
        lambda arm: arm.move_joints(HOME_Q + np.array([np.nan, 0, 0, 0, 0, 0]), 0.5, 1.0),
        lambda arm: arm.move_joints(HOME_Q + 0.1, 50.0, 1.0),  # speed above the cap
        lambda arm: arm.move_linear(np.diag([1.0, 1.0, 1.0, 1.0]) * 2, 0.1, 0.5),  # not rigid
        lambda arm: arm.move_linear(T_from_pose_vector([3.0, 0, 0.3, np.pi, 0, 0]), 0.1, 0.5),  # workspace
        lambda arm: arm.follow(JointTrajectory(t_s=np.array([0.01]), q=(HOME_Q + 0.15)[None])),  # too fast
    ],
)
def test_validator_refusals_never_reach_the_wire(bad):
    arm, _, _, log, _ = make_arm()
    with arm:
        before = len(log)
        with pytest.raises(UnsafeCommandError):
            bad(arm)
        assert len(log) == before  # not one call after the refusal
        assert arm.is_connected


@pytest.mark.parametrize(
    ("link_reports_down", "after_polls"),
    [
        # The link is down: no stop is attempted (ur_rtde would wait minutes on the dead link's stale state).
        (True, []),
        # A call failed but the link still says it is up: the stop is sent.
        (False, ["stopJ"]),
    ],
)
def test_control_link_lost_mid_move_takes_the_stop_path_and_raises(link_reports_down, after_polls):
    arm, control, _, log, _ = make_arm(moving_polls=100)
    polls = []

    def drop():
        polls.append(1)
        if len(polls) == 3:
            control.connected = not link_reports_down
            raise RuntimeError("RTDE control: socket closed")

    control.hooks["getAsyncOperationProgress"] = drop
    arm.connect()
    with pytest.raises(ConnectionLostError, match="lost"):
        arm.move_joints(HOME_Q + 0.05, 0.5, 1.0)
    names = log.names()
    assert names[names.index("moveJ") + 1 :] == ["getAsyncOperationProgress"] * 3 + after_polls
    assert not arm.is_connected
    with pytest.raises(DeviceNotConnectedError):
        arm.move_joints(HOME_Q, 0.5, 1.0)


def test_receive_link_lost_mid_servo_stops_with_servoStop():
    arm, control, receive, log, _ = make_arm()
    count = []

    def drop():
        count.append(1)
        if len(count) == 15:
            receive.connected = False

    control.hooks["servoJ"] = drop
    traj = JointTrajectory(t_s=np.array([0.2]), q=(HOME_Q + 0.02)[None])
    arm.connect()
    with pytest.raises(ConnectionLostError):
        arm.follow(traj)
    names = log.names()
    assert names[-1] == "servoStop" and names.count("servoJ") < 101  # stopped before the end (101 samples)


def test_protective_stop_during_a_move_raises_a_typed_error():
    arm, control, receive, log, _ = make_arm(moving_polls=100)
    polls = []

    def trip():
        polls.append(1)
        if len(polls) == 2:
            receive.protective = True

    control.hooks["getAsyncOperationProgress"] = trip
    with arm:
        with pytest.raises(ProtectiveStopError, match="protective stop"):
            arm.move_joints(HOME_Q + 0.05, 0.5, 1.0)
        # Nothing more is sent while the stop holds.
        n = len(log)
        with pytest.raises(ProtectiveStopError):
            arm.move_joints(HOME_Q, 0.5, 1.0)
        assert len(log) == n


def test_emergency_stop_refuses_before_sending():
    arm, _, receive, log, _ = make_arm()
    with arm:
        receive.emergency = True
        with pytest.raises(EmergencyStopError):
            arm.move_linear(ROBOT.fk_tcp(HOME_Q), 0.1, 0.5)
        assert "moveL" not in log.names()


def test_stop_from_another_thread_ends_a_blocking_move():
    arm, _, _, log, _ = make_arm(moving_polls=10**9)
    with arm:
        threading.Timer(0.05, arm.stop).start()
        arm.move_joints(HOME_Q + 0.05, 0.5, 1.0)  # returns once stopped
    names = log.names()
    assert "stopJ" in names and names.index("stopJ") > names.index("moveJ")
    assert names[-2:] == ["stopScript", "disconnect"]


def test_disconnect_ends_the_script_and_reconnect_restores_the_tcp():
    arm, control, _, log, _ = make_arm()
    arm.connect()
    control.connected = False
    with pytest.raises(ConnectionLostError):
        arm.joint_positions()
    arm.reconnect()
    assert log.names()[-2:] == ["reconnect", "setTcp"]
    np.testing.assert_array_equal(arm.joint_positions(), HOME_Q)
    arm.disconnect()
    assert log.names()[-2:] == ["stopScript", "disconnect"]


def test_refused_connection_is_a_clear_error():
    class Refusing(FakeLinks):
        def receive(self, host):
            raise RuntimeError(f"Error: Could not connect to: {host} at 30004, verify the IP")

    arm = URRtdeArm("10.0.0.9", ROBOT, links=Refusing())
    with pytest.raises(DeviceNotConnectedError, match="Remote Control"):
        arm.connect()
    assert not arm.is_connected
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError):
        arm.move_joints(HOME_Q, 0.5, 1.0)
    assert time.monotonic() - t0 < 1.0  # no retry loop: refused at once (wide bound for a loaded machine)


def test_a_guarded_line_stops_with_stopL_when_the_tool_force_rises_over_its_start():
    arm, _, receive, log, _ = make_arm(moving_polls=50)
    T = ROBOT.fk_tcp(HOME_Q)
    T[:3, 3] += [0.0, 0.0, -0.05]
    # The tool weighs on the sensor from the start (-12 N along z): only a change counts. From the third
    # read on (the first is the baseline), a touch of 45 N more pushes back.
    receive.force_at = lambda k: [0.0, 0.0, -12.0 + (45.0 if k >= 3 else 0.0), 0.0, 0.0, 0.0]
    with arm:
        assert arm.senses_contact
        assert arm.move_linear_until_contact(T, 0.05, 0.5, 40.0) is False
        assert arm.is_connected
    names = log.names()
    assert names.count("moveL") == 1 and names.index("stopL") > names.index("moveL")
    assert receive.force_reads == 3  # stopped at the first read over the limit, not later


def test_a_guarded_line_without_a_touch_completes_and_a_bad_limit_never_reaches_the_wire():
    arm, _, receive, log, _ = make_arm(moving_polls=3)
    T = ROBOT.fk_tcp(HOME_Q)
    T[:3, 3] += [0.0, 0.0, -0.05]
    receive.tcp_force = [3.0, -2.0, -12.0, 0.1, 0.0, 0.0]  # a steady tool weight and sensor offset
    with arm:
        assert arm.move_linear_until_contact(T, 0.05, 0.5, 40.0) is True
        n = len(log)
        for bad in (0.0, -1.0, float("nan")):
            with pytest.raises(InvalidInputError, match="max_force_n"):
                arm.move_linear_until_contact(T, 0.05, 0.5, bad)
        assert len(log) == n  # nothing sent for a refused limit
    assert "stopL" not in log.names()


def test_a_guarded_line_on_an_unreadable_tool_force_is_refused_or_stopped():
    arm, _, receive, log, _ = make_arm(moving_polls=50)
    T = ROBOT.fk_tcp(HOME_Q)
    T[:3, 3] += [0.0, 0.0, -0.05]
    with arm:
        receive.tcp_force = [float("nan")] * 6  # before the move: nothing is sent
        with pytest.raises(MotionFailedError, match="no guard can be kept"):
            arm.move_linear_until_contact(T, 0.05, 0.5, 40.0)
        assert "moveL" not in log.names()
        # during the move: stopped, as on a touch, and reported
        receive.tcp_force = [0.0] * 6
        receive.force_at = lambda k: [0.0] * 6 if k < 3 else [float("nan")] * 6
        with pytest.raises(MotionFailedError, match="stopped reading"):
            arm.move_linear_until_contact(T, 0.05, 0.5, 40.0)
        assert arm.is_connected
    names = log.names()
    assert names.count("moveL") == 1 and names.index("stopL") > names.index("moveL")
