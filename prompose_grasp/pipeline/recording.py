"""The arm and gripper as the loop sees them while a `Recorder` records: every command goes to the device
unchanged, and is recorded with what the device measured while it ran.

An arm command blocks until the motion ends, so the measured joints are sampled from a second thread
(`sample_hz`) through the `Arm` interface's own reading (`joint_positions`); the TCP pose is the robot
model's forward kinematics of those joints (the sampler asks the device for nothing but its joint and jaw
readings, which every backend answers from a state it keeps: RTDE's receive buffer, the MuJoCo state; the
gripper is read only while an arm command blocks the loop, so no gripper command is on its link then).
Nothing here runs when the recorder is off: `PickAndPlace` wraps the devices only for a recorder that is
`enabled`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.recorder import Recorder
from prompose_grasp.robot.interfaces import Arm, Gripper, JointCommand, JointTrajectory, LinearCommand
from prompose_grasp.robot.model import RobotModel

__all__ = ["ObservedArm", "ObservedGripper"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Joint samples per second of wall time while an arm command runs: a UR move lasts 0.5-3 s, so 30 Hz
#: draws each move with 15-90 points (its speed profile is visible) at ~0.1 ms of work per sample.
SAMPLE_HZ = 30.0


class _Sampler:
    """Records the arm's measured joints (and the jaw width) every 1 / `hz` s until stopped."""

    def __init__(self, arm: Arm, gripper: Gripper | None, robot: RobotModel, recorder: Recorder, hz: float):
        self.arm, self.gripper, self.robot, self.recorder = arm, gripper, robot, recorder
        self.period_s = 1.0 / hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="recorder-sampler", daemon=True)

    def sample(self) -> None:
        try:
            q = np.asarray(self.arm.joint_positions(), dtype=np.float64)
            self.recorder.arm_state(q, self.robot.fk_tcp(q))
            if self.gripper is not None:
                self.recorder.gripper(width_m=float(self.gripper.width()))
        except Exception as exc:  # a reading that fails (a dropped link) is the command's to report
            logger.debug("recorder: no sample (%s)", exc)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.sample()

    def __enter__(self) -> _Sampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()  # where the command left the arm


class _WrapsDevice:
    """Connecting and the connection state are the wrapped device's own."""

    wrapped: Any

    def connect(self) -> None:
        self.wrapped.connect()

    def disconnect(self) -> None:
        self.wrapped.disconnect()

    @property
    def is_connected(self) -> bool:
        return self.wrapped.is_connected


class ObservedArm(_WrapsDevice, Arm):
    """`arm`, each command recorded as sent (`Recorder.motion`) with the joints measured while it ran
    (`Recorder.arm_state`). Any other attribute is the wrapped arm's (`validator`, a simulator's timing)."""

    def __init__(
        self,
        arm: Arm,
        robot: RobotModel,
        recorder: Recorder,
        gripper: Gripper | None = None,
        sample_hz: float = SAMPLE_HZ,
    ):
        self.wrapped = arm
        self._robot = robot
        self._recorder = recorder
        self._gripper = gripper
        self._hz = float(sample_hz)

    def __getattr__(self, name: str) -> Any:  # only for what this class does not define
        return getattr(self.wrapped, name)

    def joint_positions(self) -> np.ndarray:
        return self.wrapped.joint_positions()

    def tcp_pose(self) -> np.ndarray:
        return self.wrapped.tcp_pose()

    def _recorded(self, name: str, command: Callable[[], T]) -> T:
        q0 = np.asarray(self.wrapped.joint_positions(), dtype=np.float64)
        t0 = self._recorder.clock_s()
        with _Sampler(self.wrapped, self._gripper, self._robot, self._recorder, self._hz):
            sent = command()
        self._planned(name, sent, q0, t0, self._recorder.clock_s())
        return sent

    def _planned(self, name: str, sent: object, q0: np.ndarray, t0: float, t1: float) -> None:
        """The command as planned, on the recording's clock: its motion time is drawn over the wall time
        the command took (a real arm runs in real time, so the two agree up to the settling at the end; a
        simulator runs faster or slower than real time, and its planned and measured curves would not
        line up otherwise)."""
        fk = self._robot.fk_tcp
        if isinstance(sent, JointTrajectory):
            t_s, q = sent.t_s, sent.q
            if t_s[0] > 0.0:  # the motion starts at the set-point the arm holds
                t_s, q = np.concatenate([[0.0], t_s]), np.vstack([q0, q])
            scale = (t1 - t0) / max(float(t_s[-1]), 1e-9)
            times = t0 + scale * t_s
            tcp = np.array([fk(qk)[:3, 3] for qk in q])
            self._recorder.motion(name, times, q, tcp)
        elif isinstance(sent, JointCommand):
            q = np.vstack([q0, sent.q])
            # a joint move is a straight line in joint space: its TCP path is a curve, drawn at 20 points
            tcp = np.array([fk(q0 + s * (sent.q - q0))[:3, 3] for s in np.linspace(0.0, 1.0, 20)])
            self._recorder.motion(name, np.array([t0, t1]), q, tcp)
        elif isinstance(sent, LinearCommand):
            tcp = np.array([fk(q0)[:3, 3], sent.T_base_tcp[:3, 3]])
            self._recorder.motion(name, None, None, tcp)

    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        return self._recorded("move_joints", lambda: self.wrapped.move_joints(q, speed, accel))

    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        return self._recorded("move_linear", lambda: self.wrapped.move_linear(T_base_tcp, speed, accel))

    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        return self._recorded("follow", lambda: self.wrapped.follow(trajectory))

    @property
    def senses_contact(self) -> bool:
        return bool(self.wrapped.senses_contact)

    def move_linear_until_contact(
        self, T_base_tcp: ArrayLike, speed: float, accel: float, max_force_n: float
    ) -> bool:
        reached: list[bool] = []

        def guarded() -> LinearCommand:  # drawn as the line it was sent as, wherever it stopped
            reached.append(self.wrapped.move_linear_until_contact(T_base_tcp, speed, accel, max_force_n))
            return LinearCommand(np.asarray(T_base_tcp, dtype=np.float64), float(speed), float(accel))

        self._recorded("move_linear_until_contact", guarded)
        return reached[0]

    def stop(self) -> None:
        self.wrapped.stop()


class ObservedGripper(_WrapsDevice, Gripper):
    """`gripper`, each command recorded: the commanded force, then the jaw width and the detection it
    answered with (`Recorder.gripper`). Any other attribute is the wrapped gripper's; `open_to` is wrapped
    when the gripper has one."""

    def __init__(self, gripper: Gripper, recorder: Recorder):
        self.wrapped = gripper
        self._recorder = recorder

    def __getattr__(self, name: str) -> Any:
        if name == "open_to" and callable(getattr(self.wrapped, "open_to", None)):
            return self._open_to
        return getattr(self.wrapped, name)

    def _after(self, force_n: float | None = None) -> None:
        try:
            width, detected = float(self.wrapped.width()), bool(self.wrapped.grasp_detected())
        except Exception as exc:  # the command's own fault is raised by the command
            logger.debug("recorder: no gripper reading (%s)", exc)
            return
        self._recorder.gripper(width_m=width, force_n=force_n, detected=detected)

    def open(self) -> None:
        self.wrapped.open()
        self._after(force_n=0.0)

    def _open_to(self, width_m: float) -> None:
        self.wrapped.open_to(width_m)  # type: ignore[attr-defined]
        self._after(force_n=0.0)

    def close(self, force: float) -> bool:
        self._recorder.gripper(force_n=float(force))
        held = self.wrapped.close(force)
        self._after(force_n=float(force))
        return held

    def grasp_detected(self) -> bool:
        return self.wrapped.grasp_detected()

    def width(self) -> float:
        return self.wrapped.width()
