"""IOSuctionGripper: valve on a digital output, vacuum switch on a digital input, through the arm's links."""

from __future__ import annotations

import numpy as np
import pytest
from rtde_fakes import CallLog, FakeControl, FakeIO, FakeLinks, FakeReceive

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError
from prompose_grasp.geometry.se3 import pose_vector_from_T
from prompose_grasp.hardware import IOSuctionGripper, SuctionIOConfig, URRtdeArm, URRtdeConfig
from prompose_grasp.robot import HOME_Q, load_robot

ROBOT = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.1])


def make(seals: bool):
    log = CallLog()
    receive = FakeReceive(HOME_Q, pose_vector_from_T(ROBOT.fk_tcp(HOME_Q)))

    def valve(pin, level):  # the vacuum switch (input 3) follows the valve when a part seals the cup
        if pin == 2 and seals:
            receive.inputs = (receive.inputs | 1 << 3) if level else (receive.inputs & ~(1 << 3))

    links = FakeLinks(FakeControl(log), receive, FakeIO(log, on_output=valve))
    arm = URRtdeArm("10.0.0.2", ROBOT, config=URRtdeConfig(use_io=True), links=links)
    cfg = SuctionIOConfig(
        vacuum_output=2, vacuum_input=3, blow_off_output=4, blow_off_s=0.01, seal_timeout_s=0.1
    )
    return arm, IOSuctionGripper(arm, cfg), log


def test_close_switches_the_valve_and_reads_the_vacuum_switch():
    arm, gripper, log = make(seals=True)
    with arm, gripper:
        assert gripper.close(50.0) is True
        assert gripper.grasp_detected()
        gripper.open()
        assert not gripper.grasp_detected()
    outputs = [args for name, args in log if name == "setStandardDigitalOut"]
    assert outputs == [(2, True), (2, False), (4, True), (4, False)]  # vacuum on; off, blow-off pulse


def test_no_seal_within_the_timeout_is_no_grasp():
    arm, gripper, _ = make(seals=False)
    with arm, gripper:
        assert gripper.close(50.0) is False
        assert gripper.width() == 0.0


def test_needs_a_connected_arm_with_io():
    arm, gripper, _ = make(seals=True)
    with pytest.raises(DeviceNotConnectedError):
        gripper.connect()
    arm.config = URRtdeConfig(use_io=False)
    with arm, pytest.raises(DeviceNotConnectedError, match="use_io"):
        gripper.connect()


def test_config_checks_pins():
    with pytest.raises(InvalidInputError):
        SuctionIOConfig(vacuum_output=9)
    with pytest.raises(InvalidInputError):
        SuctionIOConfig(vacuum_output=1, tool_output=True, blow_off_output=3)
    assert np.isfinite(SuctionIOConfig().seal_timeout_s)
