"""The real ur_rtde receive library against a loopback RTDE server running in another process.

The server (`rtde_loopback.py`) speaks RTDE on port 30004 of a private loopback address (127.x.y.z, so
parallel test runs do not collide); ur_rtde holds the GIL while it waits for packages, hence the separate
process. The control link is our stand-in (`rtde_fakes.FakeControl`): a controller script cannot run here.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import socket
import time

import numpy as np
import pytest

pytest.importorskip("rtde_receive", reason="ur_rtde is not installed (pip install 'prompose-grasp[ur]')")

from rtde_fakes import CallLog, FakeControl, FakeLinks
from rtde_loopback import serve_rtde

from prompose_grasp.errors import DeviceNotConnectedError
from prompose_grasp.geometry.se3 import pose_vector_from_T
from prompose_grasp.hardware import (
    RECEIVE_VARIABLES,
    ConnectionLostError,
    EmergencyStopError,
    ProtectiveStopError,
    URRtdeArm,
    URRtdeConfig,
    URRtdeLinks,
)
from prompose_grasp.robot import load_robot

ROBOT = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.145])
Q = np.array([0.3, -1.2, 1.5, -1.9, -1.6, 0.4])

PROTECTIVE_STOPPED_BIT = 1 << 2  # safety_status_bits, RTDE guide
EMERGENCY_STOPPED_BIT = 1 << 7


def _free_loopback_host() -> str:
    """A 127.x.y.z address with nothing on port 30004."""
    rng = random.Random(os.getpid() ^ time.monotonic_ns())
    for _ in range(50):
        host = f"127.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
        with socket.socket() as s:
            try:
                s.bind((host, 30004))
            except OSError:
                continue
            return host
    pytest.skip("no free loopback address for port 30004")


class Server:
    def __init__(self, state: dict, drop_after_s: float | None = None):
        ctx = multiprocessing.get_context("spawn")
        self.host = _free_loopback_host()
        ready = ctx.Event()
        self.process = ctx.Process(
            target=serve_rtde, args=(self.host, state, ready, drop_after_s), daemon=True
        )
        self.process.start()
        if not ready.wait(30):
            self.stop()
            pytest.fail("the loopback RTDE server did not start")

    def stop(self) -> None:
        self.process.terminate()
        self.process.join(5)


@pytest.fixture
def server(request):
    state = {
        "actual_q": Q.tolist(),
        "actual_TCP_pose": pose_vector_from_T(ROBOT.fk_tcp(Q)).tolist(),
        "safety_status_bits": 1,  # normal mode
        "robot_mode": 7,  # running
        "actual_digital_input_bits": 1 << 3,  # a vacuum switch on input 3
    }
    state.update(getattr(request, "param", {}))
    drop = state.pop("drop_after_s", None)
    srv = Server(state, drop)
    yield srv
    srv.stop()


def _wait_for(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def test_real_receive_interface_reads_joints_and_tcp_pose(server):
    receive = URRtdeLinks(receive_frequency_hz=125.0).receive(server.host)
    try:
        assert receive.isConnected()
        # Doubles cross the wire bit-exact (big-endian IEEE 754 both ways).
        assert _wait_for(lambda: receive.getActualQ() == Q.tolist())
        assert receive.getActualTCPPose() == pose_vector_from_T(ROBOT.fk_tcp(Q)).tolist()
        assert not receive.isProtectiveStopped() and not receive.isEmergencyStopped()
        assert receive.getDigitalInState(3) and not receive.getDigitalInState(2)
    finally:
        receive.disconnect()


def test_arm_reads_state_through_the_real_receive_link(server):
    log = CallLog()
    real = URRtdeLinks(receive_frequency_hz=125.0)
    links = FakeLinks(control=FakeControl(log), receive=None)
    links.receive = real.receive  # the real library for reading, our stand-in for commands
    with URRtdeArm(server.host, ROBOT, links=links) as arm:
        assert _wait_for(lambda: np.array_equal(arm.joint_positions(), Q))
        # The pose vector of the model's FK comes back as the same transform (rotation-vector round trip).
        np.testing.assert_allclose(arm.tcp_pose(), ROBOT.fk_tcp(Q), atol=1e-12)


@pytest.mark.parametrize(
    ("server", "error"),
    [
        ({"safety_status_bits": 1 | PROTECTIVE_STOPPED_BIT}, ProtectiveStopError),
        ({"safety_status_bits": EMERGENCY_STOPPED_BIT}, EmergencyStopError),
    ],
    indirect=["server"],
)
def test_safety_stops_reported_by_the_controller_refuse_commands(server, error):
    log = CallLog()
    real = URRtdeLinks(receive_frequency_hz=125.0)
    links = FakeLinks(control=FakeControl(log))
    links.receive = real.receive
    with URRtdeArm(server.host, ROBOT, links=links) as arm:
        assert _wait_for(lambda: np.array_equal(arm.joint_positions(), Q))
        with pytest.raises(error):
            arm.move_joints(Q + 0.05, 0.5, 1.0)
    assert "moveJ" not in log.names()


def test_connection_refused_is_a_clear_error_at_once():
    host = _free_loopback_host()  # nothing listens there
    arm = URRtdeArm(host, ROBOT)  # the real ur_rtde links
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match=rf"{host}.*30004.*Remote Control"):
        arm.connect()
    # The bound: refused at once, reported in under 2 s (measured: well under 10 ms when idle).
    assert time.monotonic() - t0 < 2.0


@pytest.mark.parametrize("server", [{"drop_after_s": 0.5}], indirect=True)
def test_connection_lost_mid_motion_stops_and_raises(server):
    log = CallLog()
    real = URRtdeLinks(receive_frequency_hz=125.0)
    control = FakeControl(log, moving_polls=10**9)  # a move that would never finish by itself
    links = FakeLinks(control=control)
    links.receive = real.receive
    arm = URRtdeArm(server.host, ROBOT, config=URRtdeConfig(poll_period_s=0.005), links=links)
    arm.connect()
    assert _wait_for(lambda: np.array_equal(arm.joint_positions(), Q))
    with pytest.raises(ConnectionLostError, match="lost"):
        arm.move_joints(Q + 0.05, 0.5, 1.0)
    names = log.names()
    assert names.index("stopJ") > names.index("moveJ")  # the stop path was taken
    assert not arm.is_connected
    # The server still accepts: reconnect reads the state again.
    arm.reconnect()
    assert _wait_for(lambda: np.array_equal(arm.joint_positions(), Q))
    arm.disconnect()


def test_receive_recipe_is_what_the_arm_reads():
    assert {"actual_q", "actual_TCP_pose", "safety_status_bits", "actual_digital_input_bits"} <= set(
        RECEIVE_VARIABLES
    )


def test_dry_run_reads_the_start_joints_over_a_receive_only_link(server):
    from prompose_grasp.hardware.run import _current_q

    # The default links (controller-rate recipe), receive only: a dry run opens no control link.
    np.testing.assert_array_equal(_current_q(server.host), Q)
