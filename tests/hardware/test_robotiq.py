"""RobotiqGripper against a loopback URCap socket server (simulated 2F-85)."""

from __future__ import annotations

import socket

import pytest
from robotiq_loopback import RobotiqLoopback

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError
from prompose_grasp.hardware import ConnectionLostError, GripperError, RobotiqConfig, RobotiqGripper

FAST = RobotiqConfig(timeout_s=2.0, poll_period_s=0.001)


@pytest.fixture
def server():
    srv = RobotiqLoopback(object_position=150)
    yield srv
    srv.close()


def test_connect_activates_then_enables_motion(server):
    with RobotiqGripper("127.0.0.1", server.port, FAST):
        pass
    assert server.log[0] == "GET STA"
    assert server.log[1] == "SET ACT 1"
    assert server.log[-1] == "SET GTO 1"
    assert server.vars["STA"] == 3


def test_already_active_gripper_is_not_reactivated(server):
    server.vars.update(ACT=1, STA=3)
    with RobotiqGripper("127.0.0.1", server.port, FAST):
        pass
    assert "SET ACT 1" not in server.log


def test_close_on_an_object_reports_the_grasp_and_its_width(server):
    with RobotiqGripper("127.0.0.1", server.port, FAST) as g:
        assert g.close(force=127.5) is True
        assert g.grasp_detected()
        # Position 150 of 255 on an 85 mm stroke: 85 * 105 / 255 = 35 mm.
        assert g.width() == pytest.approx(0.085 * 105 / 255, abs=1e-12)  # exact arithmetic, float rounding
        sets = [line for line in server.log if line.startswith("SET")]
        # Force 127.5 N is halfway through 20..235 N: FOR 128 (rounded from 127.5).
        assert sets[-4:] == ["SET SPE 255", "SET FOR 128", "SET POS 255", "SET GTO 1"]
        g.open()
        assert not g.grasp_detected()
        assert g.width() == pytest.approx(0.085, abs=1e-12)  # position 0 is the full opening


def test_close_on_nothing_reports_no_grasp(server):
    server.object_position = None
    with RobotiqGripper("127.0.0.1", server.port, FAST) as g:
        assert g.close(force=60.0) is False
        assert g.width() == 0.0


def test_force_outside_the_range_is_refused_before_sending(server):
    with RobotiqGripper("127.0.0.1", server.port, FAST) as g:
        n = len(server.log)
        with pytest.raises(InvalidInputError, match=r"\[20\.0, 235\.0\]"):
            g.close(force=500.0)
        assert len(server.log) == n


def test_unexpected_reply_is_a_gripper_error(server):
    server.reply_override["SET POS 255"] = "?"
    with RobotiqGripper("127.0.0.1", server.port, FAST) as g:
        with pytest.raises(GripperError, match="refused 'SET POS 255'"):
            g.close(force=60.0)


def test_socket_closed_mid_command_is_connection_lost(server):
    server.drop_on = "SET POS"
    g = RobotiqGripper("127.0.0.1", server.port, FAST)
    g.connect()
    with pytest.raises(ConnectionLostError):
        g.close(force=60.0)
    assert not g.is_connected


def test_nothing_listening_is_a_clear_error():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free, and closed again below
    with pytest.raises(DeviceNotConnectedError, match="URCap"):
        RobotiqGripper("127.0.0.1", port, FAST).connect()
