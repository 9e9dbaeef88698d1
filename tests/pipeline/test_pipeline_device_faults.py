"""PickAndPlace on fakes that fail mid-run: every device fault ends in its typed outcome after the stop path.

The arm and gripper here are the in-memory fakes with one fault injected at a known command (the estimator
is the oracle stub of `test_pipeline_pick_faults`, named so). A pick sends, in order: the joint move to the
pre-grasp (motion 1), the approach line (motion 2), the gripper's close, the lift line (motion 3).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_pipeline_pick_faults import PICK, ROBOT, Camera, K, OracleEstimator

from prompose_grasp.errors import DeviceFault, ObjectNotFoundError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.pipeline.outcome import DEVICE_FAULT_REASONS, REASONS
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.robot import FakeArm, FakeGripper
from prompose_grasp.robot.interfaces import (
    ConnectionLostError,
    EmergencyStopError,
    GripperError,
    MotionFailedError,
    ProtectiveStopError,
    RGBDFrame,
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

    def fake_run_command(spec, text, recorder=None):
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


# ---------------------------------------------------------------------------------------------------------
# Verification fails closed: a re-observation frame that cannot be trusted, or one that sees nothing, is no
# evidence of a lift.

BOX_TOP_Z = 0.06  # the oracle's box: centre z 0.03 m, 6 cm tall (object +y is base +z)


class BoxCamera(Camera):
    """`Camera`'s table 1 m below with the oracle's box on it (its top face at `BOX_TOP_Z`, over its
    footprint x -0.5 +- 0.025, y 0.15 +- 0.03 m) while `box_on(call)` is True; capture numbers in `faulty`
    give a frame with no depth at all ("dropout"), or with half the resolution and the intrinsics scaled
    to it ("rescaled")."""

    def __init__(self, box_on=lambda call: True, faulty=(), fault="dropout"):
        super().__init__()
        self.box_on, self.faulty, self.fault = box_on, set(faulty), fault

    def capture(self) -> RGBDFrame:
        frame = super().capture()
        depth = frame.depth_m.copy()
        if self.box_on(self.calls):
            u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
            z = 1.0 - BOX_TOP_Z
            x = -0.5 + (u - K.cx) / K.fx * z  # base x of the pixel's ray at the box top (camera x = base x)
            y = -(v - K.cy) / K.fy * z  # camera y = -base y
            depth[(np.abs(x + 0.5) <= 0.025) & (np.abs(y - 0.15) <= 0.03)] = z
        if self.calls in self.faulty and self.fault == "dropout":
            depth[:] = 0.0
        if self.calls in self.faulty and self.fault == "rescaled":
            half = CameraIntrinsics(K.fx / 2, K.fy / 2, (K.cx - 0.5) / 2, (K.cy - 0.5) / 2, 80, 60)
            return RGBDFrame(frame.rgb[::2, ::2], depth[::2, ::2], half, frame.timestamp_s, frame.T_base_cam)
        return RGBDFrame(frame.rgb, depth, K, frame.timestamp_s, frame.T_base_cam)


class SeesNothingAfterTheFirst(OracleEstimator):
    """Finds the box in the first frame; after that, nothing (the re-observation "sees nothing")."""

    def estimate(self, frame, prompt):
        if self.calls >= 1:
            self.calls += 1
            raise ObjectNotFoundError(f"no object matches {prompt!r}")
        return super().estimate(frame, prompt)


class LiftedAfterTheFirst(OracleEstimator):
    """The box as estimated, then 12 cm higher (in the hand) from the second frame on."""

    def estimate(self, frame, prompt):
        if self.calls == 1:
            self.t_base = self.t_base + np.array([0.0, 0.0, 0.12])
        return super().estimate(frame, prompt)


def _run_reobserve(camera, estimator):
    """One grasp of the 5 cm box, re-observed after the lift; the outcome and the gripper."""
    cfg = PickConfig(reobserve=True, max_estimates=1, grasps_per_estimate=1)
    arm, gripper = FakeArm(ROBOT), FaultyGripper()
    arm.connect()
    gripper.connect()
    pnp = PickAndPlace(arm, gripper, camera, estimator, ROBOT, "parallel_jaw", config=cfg)
    return pnp.run(PICK), gripper


@pytest.mark.parametrize("fault", ["dropout", "rescaled"])
def test_an_untrusted_re_observation_is_no_lift_and_the_object_is_set_down(fault):
    # The gripper holds the box and every re-observation frame has no depth (or changed resolution and
    # intrinsics): the lift cannot be verified. Not a success: "camera_failed", the box set down where it was
    # picked and the gripper opened.
    camera = BoxCamera(faulty=range(2, 10**6), fault=fault)
    outcome, gripper = _run_reobserve(camera, SeesNothingAfterTheFirst())
    assert outcome.reason == "camera_failed", outcome.message
    assert "could not be verified" in outcome.message and "set down where it was picked" in outcome.message
    assert ("depth is gone" if fault == "dropout" else "intrinsics changed") in outcome.message
    assert gripper.commands[-2:] == ["close", "open"]
    assert camera.calls == 1 + 3  # the pick's frame, then `camera_retries` refused re-observation frames


@pytest.mark.parametrize("fault", ["dropout", "rescaled"])
def test_one_untrusted_frame_is_captured_again(fault):
    # Only the first re-observation frame is faulty: the next one is used, and it sees the box lifted.
    camera = BoxCamera(box_on=lambda call: call == 1, faulty={2}, fault=fault)
    outcome, _ = _run_reobserve(camera, LiftedAfterTheFirst())
    assert outcome.success, outcome.message
    assert camera.calls == 3


def test_seeing_nothing_while_the_depth_still_shows_the_object_is_slipped():
    # The estimator finds nothing in the re-observation, but the depth where the box stood still reads its
    # top face: it did not leave (the gripper's "held" notwithstanding).
    outcome, gripper = _run_reobserve(BoxCamera(), SeesNothingAfterTheFirst())
    assert outcome.reason == "slipped" and "still reads its surface" in outcome.message
    assert gripper.commands[-1] == "open"


def test_seeing_nothing_where_the_object_stood_is_seen_empty_is_a_lift():
    # The box is gone from where it stood (the table is seen there, 6 cm deeper): lifted out of view.
    outcome, _ = _run_reobserve(BoxCamera(box_on=lambda call: call == 1), SeesNothingAfterTheFirst())
    assert outcome.success, outcome.message


class _HoleOverTheBox(BoxCamera):
    """After the pick's frame, the depth has a hole just over where the box stood (the rest of the frame
    reads): no reading tells whether the box left."""

    def capture(self):
        frame = super().capture()
        if self.calls == 1:
            return frame
        depth = frame.depth_m.copy()
        depth[0:25, 65:95] = 0.0  # the box's window (u 71-88, v 2-22) and a margin
        return RGBDFrame(frame.rgb, depth, K, frame.timestamp_s, frame.T_base_cam)


def test_seeing_nothing_and_no_depth_where_it_stood_with_empty_jaws_is_no_lift():
    # The jaws held the box when they closed and report nothing by the re-observation (it slipped out): no
    # reading tells where it is, so no lift: camera_failed, the hand set down and opened.
    class LostAfterTheCheck(FaultyGripper):
        checks = 0

        def grasp_detected(self):
            self.checks += 1
            return self.checks == 1

    cfg = PickConfig(reobserve=True, max_estimates=1, grasps_per_estimate=1)
    arm, gripper = FakeArm(ROBOT), LostAfterTheCheck()
    arm.connect()
    gripper.connect()
    estimator = SeesNothingAfterTheFirst()
    pnp = PickAndPlace(arm, gripper, _HoleOverTheBox(), estimator, ROBOT, "parallel_jaw", config=cfg)
    outcome = pnp.run(PICK)
    assert outcome.reason == "camera_failed" and "too few depth readings" in outcome.message, outcome.message
    assert gripper.checks >= 2  # the re-observation asked the gripper
    assert gripper.commands[-1] == "open"


def test_seeing_nothing_and_no_depth_where_it_stood_while_holding_is_a_lift():
    # The jaws hold the 5 cm box and the depth has no reading where it stood: the box in the hand is in front
    # of that place, nearer than the sensor reads (a carton lifted towards a camera above a conveyor).
    outcome, _ = _run_reobserve(_HoleOverTheBox(), SeesNothingAfterTheFirst())
    assert outcome.success, outcome.message


def test_a_camera_that_changes_mode_between_rounds_is_camera_failed():
    # Round 1 slips (the jaws close on nothing); every frame after the first comes at half the resolution
    # with its intrinsics scaled to it: round 2's observation is refused, not estimated on another mode.
    camera = BoxCamera(faulty=range(2, 10**6), fault="rescaled")
    cfg = PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=1)
    arm, gripper = FakeArm(ROBOT), FakeGripper(object_width_m=None)
    arm.connect()
    gripper.connect()
    pnp = PickAndPlace(arm, gripper, camera, OracleEstimator(), ROBOT, "parallel_jaw", config=cfg)
    outcome = pnp.run(PICK)
    assert outcome.reason == "camera_failed" and "intrinsics changed mid-run" in outcome.message
    assert [a.result for a in outcome.attempts] == ["slipped"]
    assert "(160, 120, 300, 300, 79.5, 59.5) -> (80, 60, 150, 150, 39.5, 29.5)" in outcome.message
