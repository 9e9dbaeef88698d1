"""PickAndPlace on fakes that fail mid-run: every device fault ends in its typed outcome after the stop path.

The arm and gripper here are the in-memory fakes with one fault injected at a known command (the estimator
is the oracle stub of `test_pipeline_pick_faults`, named so). A pick sends, in order: the joint move to the
pre-grasp (motion 1), the approach line (motion 2), the gripper's close, the lift line (motion 3).
"""

from __future__ import annotations

import pytest
from test_pipeline_pick_faults import PICK, ROBOT, Camera, OracleEstimator

from prompose_grasp.errors import DeviceFault
from prompose_grasp.pipeline.outcome import DEVICE_FAULT_REASONS, REASONS
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.robot import FakeArm, FakeGripper
from prompose_grasp.robot.interfaces import (
    ConnectionLostError,
    EmergencyStopError,
    GripperError,
    MotionFailedError,
    ProtectiveStopError,
)

FAULTS = [
    (ProtectiveStopError("move_linear: the arm is in a protective stop"), "protective_stop"),
    (EmergencyStopError("move_linear: the arm is emergency stopped"), "emergency_stop"),
    (ConnectionLostError("move_linear: the link to the UR controller was lost"), "connection_lost"),
    (MotionFailedError("move_linear: the controller did not accept the command"), "motion_failed"),
]
#: Motion commands of a pick, counted from 1 (module docstring).
APPROACH, LIFT = 2, 3


class FaultyArm(FakeArm):
    """A FakeArm whose `fault_at`-th motion command raises `fault` (nothing moves); it records every command
    the loop gives it after that one (`after`: motions and stops, by name)."""

    def __init__(self, fault: Exception, fault_at: int):
        super().__init__(ROBOT)
        self.fault, self.fault_at = fault, fault_at
        self.motions = 0
        self.after: list[str] = []

    def _motion(self, name, fn, *args):
        self.motions += 1
        if self.motions == self.fault_at:
            raise self.fault
        if self.motions > self.fault_at:
            self.after.append(name)
        return fn(*args)

    def move_joints(self, q, speed, accel):
        return self._motion("move_joints", super().move_joints, q, speed, accel)

    def move_linear(self, T_base_tcp, speed, accel):
        return self._motion("move_linear", super().move_linear, T_base_tcp, speed, accel)

    def follow(self, trajectory):
        return self._motion("follow", super().follow, trajectory)

    def stop(self):
        if self.motions >= self.fault_at:
            self.after.append("stop")
        super().stop()


class FaultyGripper(FakeGripper):
    """A FakeGripper holding a 5 cm object whose `close` raises `fault` (the jaws stopped on the object);
    `open` raises `open_fault` when given. `commands` lists what it was told, in order."""

    def __init__(self, fault: Exception | None = None, open_fault: Exception | None = None):
        super().__init__(object_width_m=0.05)
        self.fault, self.open_fault = fault, open_fault
        self.commands: list[str] = []

    def open(self):
        self.commands.append("open")
        if self.open_fault is not None and "close" in self.commands:
            raise self.open_fault
        super().open()

    def close(self, force):
        self.commands.append("close")
        held = super().close(force)
        if self.fault is not None:
            raise self.fault
        return held


def _run(arm, gripper, config=None):
    """Run the pick on connected fakes, left connected so the test can read the state the loop left."""
    cfg = config or PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=2)
    arm.connect()
    gripper.connect()
    pnp = PickAndPlace(arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=cfg)
    return pnp.run(PICK)


def test_the_fault_reasons_are_reasons_and_faults():
    assert set(DEVICE_FAULT_REASONS) <= set(REASONS)
    assert set(DEVICE_FAULT_REASONS) == {r for _, r in FAULTS} | {"gripper_failed"}
    for exc, _ in FAULTS:
        assert isinstance(exc, DeviceFault)
    assert isinstance(GripperError("x"), DeviceFault)


@pytest.mark.parametrize(("fault", "reason"), FAULTS)
def test_a_fault_on_the_approach_ends_typed_with_the_gripper_open(fault, reason):
    arm, gripper = FaultyArm(fault, APPROACH), FakeGripper(object_width_m=0.05)
    outcome = _run(arm, gripper)
    assert outcome.reason == reason and not outcome.success, outcome.message
    # The attempt in progress is recorded with the fault; no other grasp or round was tried.
    assert [a.result for a in outcome.attempts] == [reason]
    assert str(fault) in outcome.message and "the gripper is open" in outcome.message
    # Stop path: after an e-stop or a lost link nothing more reaches the arm (not even a stop); after the
    # others one stop command and no motion.
    expected = [] if reason in ("emergency_stop", "connection_lost") else ["stop"]
    assert arm.after == expected
    assert gripper.width() == pytest.approx(gripper.max_width_m)  # it never closed


@pytest.mark.parametrize(("fault", "reason"), FAULTS)
def test_a_fault_on_the_lift_leaves_the_object_held_and_says_so(fault, reason):
    # The jaws hold the object and the arm may have raised it: opening would drop it. The gripper stays
    # closed, and the outcome says so (never clamped silently).
    arm, gripper = FaultyArm(fault, LIFT), FakeGripper(object_width_m=0.05)
    outcome = _run(arm, gripper)
    assert outcome.reason == reason, outcome.message
    assert "still closed on the object" in outcome.message
    assert gripper.grasp_detected() and gripper.width() == pytest.approx(0.05)
    expected = [] if reason in ("emergency_stop", "connection_lost") else ["stop"]
    assert arm.after == expected


@pytest.mark.parametrize(
    ("fault", "reason"),
    [
        (GripperError("Robotiq: close did not finish within 5.0 s"), "gripper_failed"),
        (ConnectionLostError("Robotiq gripper at 10.0.0.2:63352: connection reset"), "connection_lost"),
    ],
)
def test_a_gripper_fault_while_closing_opens_it_on_the_support(fault, reason):
    # The fault strikes at the grasp pose, before the lift: the object still rests on the table, so opening
    # cannot drop it. A gripper fault stops the arm; a lost link sends the arm nothing more.
    arm, gripper = FaultyArm(RuntimeError("not reached"), 10**6), FaultyGripper(fault)
    outcome = _run(arm, gripper)
    assert outcome.reason == reason, outcome.message
    assert gripper.commands[-2:] == ["close", "open"]
    assert "the gripper was opened" in outcome.message
    assert arm.motions == 2  # pre-grasp and approach; no lift
    assert arm.stopped == (reason == "gripper_failed")


def test_a_gripper_that_cannot_open_after_its_fault_is_reported_closed():
    fault, open_fault = GripperError("Robotiq refused 'SET POS 255'"), GripperError("Robotiq: no reply")
    outcome = _run(FaultyArm(RuntimeError("not reached"), 10**6), FaultyGripper(fault, open_fault))
    assert outcome.reason == "gripper_failed"
    assert "still closed: opening it failed" in outcome.message and "no reply" in outcome.message


def test_an_e_stop_while_closed_on_the_support_sends_the_gripper_nothing():
    # The e-stop shows at the close (a gripper switched through the controller's IO, which an e-stopped
    # controller refuses): the object is on the table, yet after an e-stop nothing at all is sent, to the arm
    # or the gripper; the gripper stays closed and the message says so.
    arm = FaultyArm(RuntimeError("not reached"), 10**6)
    gripper = FaultyGripper(EmergencyStopError("set_tool_digital_out: the arm is emergency stopped"))
    outcome = _run(arm, gripper)
    assert outcome.reason == "emergency_stop"
    assert gripper.commands[-1] == "close" and arm.motions == 2 and not arm.stopped
    assert "still closed (nothing is sent after an e-stop)" in outcome.message


def test_a_fault_while_going_home_between_rounds_is_typed():
    # The jaws close on nothing (round 1 slips), then the move home before round 2 hits a protective stop.
    # motions: pre-grasp, approach, lift, back off, then home (the 5th)
    arm = FaultyArm(ProtectiveStopError("move_joints: protective stop"), 5)
    outcome = _run(arm, FakeGripper(object_width_m=None))
    assert outcome.reason == "protective_stop", outcome.message
    assert [a.result for a in outcome.attempts] == ["slipped"]
    assert arm.after == ["stop"]


@pytest.mark.parametrize(
    ("result", "status"),
    [
        ("success", 0),
        ("slipped", 1),
        ("protective_stop", 3),
        (ConnectionLostError("connect: the link to the UR controller at 10.0.0.2 was lost"), 3),
        (MotionFailedError("move_joints: the controller never reported the move running"), 3),
    ],
)
def test_the_cli_exit_status_says_device_fault_not_bad_input(tmp_path, monkeypatch, capsys, result, status):
    # `prompose-grasp run` exits 3 on a device fault, whether the loop ended in a fault outcome or the fault
    # was raised outside it (connecting); 1 on another failed outcome; 2 stays bad input.
    from prompose_grasp import cli
    from prompose_grasp.hardware import run as hardware_run
    from prompose_grasp.pipeline.outcome import PickOutcome

    def fake_run_command(spec, text):
        if isinstance(result, Exception):
            raise result
        return hardware_run.RunResult(PickOutcome(result, "as injected"), (), (), False)

    monkeypatch.setattr(hardware_run, "run_command", fake_run_command)
    calibration = tmp_path / "hand_eye.yaml"
    calibration.write_text("T_base_cam: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    argv = ["run", "--host", "10.0.0.2", "--gripper", "robotiq", "--camera", "realsense", "--command",
            "pick up the box", "--calibration", str(calibration)]  # fmt: skip
    assert cli.main(argv) == status
    err = capsys.readouterr().err
    if isinstance(result, Exception):
        assert err.count("\n") == 1 and "device fault" in err  # one line
    assert cli.exit_status(result if isinstance(result, str) else "motion_failed") == status
    for reason in DEVICE_FAULT_REASONS:
        assert cli.exit_status(reason) == cli.EXIT_DEVICE_FAULT != cli.EXIT_BAD_INPUT
