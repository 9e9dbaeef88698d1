"""`URRtdeArm`: a Universal Robots arm over RTDE (the `ur_rtde` library), behind the `Arm` interface.

```
with URRtdeArm("192.168.1.10", load_robot("ur5e", tcp_offset=[0, 0, 0.145])) as arm:
    arm.move_joints(q, speed=0.5, accel=1.0)          # validated first, then moveJ
```

Every motion command goes through the shared `CommandValidator` (limits, step, speed, workspace) before a
byte leaves: a refused command raises `UnsafeCommandError` and nothing is sent. Moves are sent asynchronously
and watched until they finish, so that

- a protective or emergency stop during a move raises `ProtectiveStopError` / `EmergencyStopError`;
- a dropped link (control or receive) takes the stop path (`stopJ`/`stopL`, or `servoStop` while servoing,
  where the control link still answers), marks the arm disconnected and raises `ConnectionLostError`. With
  the control link itself gone no stop can be sent: the controller finishes the move it was given (a UR
  controller does not stop when its RTDE client goes; a servo stream holds its last setpoint);
- a move the controller refuses, never starts, or does not finish in time is stopped and raises
  `MotionFailedError` (the link stays up);
- `stop()` from another thread ends the move (the blocked call then returns normally).

`disconnect()` stops any motion and ends the controller script (`stopScript`).

The three ur_rtde interfaces are opened through an `RtdeLinks` factory, the boundary the tests replace
(`URRtdeLinks` opens the real ones). The arm calls only the methods listed in `RtdeControlLink`,
`RtdeReceiveLink` and `RtdeIOLink`. ur_rtde facts this relies on: the constructors raise
`RuntimeError("... Could not connect to: HOST at 30004 ...")` at once when nothing listens; e-Series arms
accept the control script only in Remote Control mode; `RTDEReceiveInterface` keeps answering the last state
after its link drops, so the arm checks `isConnected()` rather than trusting the values.

This module stays one file although it is longer than the others: it is one adapter class around one SDK.
Its parts (the link protocols the tests replace, the config, the move / watch / stop paths of `URRtdeArm`)
share the arm's link state and its stop path, and a reader checking what reaches the controller wants them
side by side.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp._optional import require
from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError, UnreachableError
from prompose_grasp.geometry.se3 import T_from_pose_vector, pose_vector_from_T, rotation_angle
from prompose_grasp.hardware.errors import (
    ConnectionLostError,
    EmergencyStopError,
    MotionFailedError,
    ProtectiveStopError,
)
from prompose_grasp.robot.interfaces import Arm, JointCommand, JointTrajectory, LinearCommand
from prompose_grasp.robot.model import RobotModel, load_robot
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

__all__ = [
    "RECEIVE_VARIABLES",
    "RTDE_PORT",
    "RtdeControlLink",
    "RtdeIOLink",
    "RtdeLinks",
    "RtdeReceiveLink",
    "URRtdeArm",
    "URRtdeConfig",
    "URRtdeLinks",
]

logger = logging.getLogger(__name__)

#: The controller's RTDE port (fixed by Universal Robots; ur_rtde always connects there).
RTDE_PORT = 30004

#: After one link is found lost, how long the control link may take to report itself down too before a
#: stop is sent through it (a few hundred RTDE cycles; its receive thread notices an EOF within one) [s].
LINK_VERDICT_S = 0.25

#: How long `reconnect` waits for a re-uploaded control script to run (ur_rtde's own wait at connect) [s].
SCRIPT_START_TIMEOUT_S = 5.0

#: The output recipe the receive link asks for: what the arm reads, nothing more.
RECEIVE_VARIABLES = (
    "timestamp",
    "actual_q",
    "actual_TCP_pose",
    "actual_TCP_force",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "actual_digital_input_bits",
    "actual_digital_output_bits",
)


class RtdeControlLink(Protocol):
    """The part of `rtde_control.RTDEControlInterface` the arm uses (same names and arguments)."""

    def setTcp(self, tcp_offset: list[float]) -> bool: ...
    def moveJ(self, q: list[float], speed: float, acceleration: float, asynchronous: bool) -> bool: ...
    def moveL(self, pose: list[float], speed: float, acceleration: float, asynchronous: bool) -> bool: ...
    def getAsyncOperationProgress(self) -> int: ...
    def initPeriod(self) -> Any: ...
    def servoJ(
        self,
        q: list[float],
        speed: float,
        acceleration: float,
        time: float,
        lookahead_time: float,
        gain: float,
    ) -> bool: ...
    def waitPeriod(self, t_cycle_start: Any) -> None: ...
    def servoStop(self, a: float) -> bool: ...
    def stopJ(self, a: float, asynchronous: bool) -> None: ...
    def stopL(self, a: float, asynchronous: bool) -> None: ...
    def stopScript(self) -> None: ...
    def isProgramRunning(self) -> bool: ...
    def reuploadScript(self) -> bool: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...
    def disconnect(self) -> None: ...


class RtdeReceiveLink(Protocol):
    """The part of `rtde_receive.RTDEReceiveInterface` the arm and the suction gripper use."""

    def getActualQ(self) -> list[float]: ...
    def getActualTCPPose(self) -> list[float]: ...
    def getActualTCPForce(self) -> list[float]: ...
    def isProtectiveStopped(self) -> bool: ...
    def isEmergencyStopped(self) -> bool: ...
    def getDigitalInState(self, input_id: int) -> bool: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...
    def disconnect(self) -> None: ...


class RtdeIOLink(Protocol):
    """The part of `rtde_io.RTDEIOInterface` the suction gripper uses."""

    def setStandardDigitalOut(self, output_id: int, signal_level: bool) -> bool: ...
    def setToolDigitalOut(self, output_id: int, signal_level: bool) -> bool: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...
    def disconnect(self) -> None: ...


class RtdeLinks(Protocol):
    """Opens the three links to a controller (the boundary tests replace)."""

    def control(self, host: str) -> RtdeControlLink: ...
    def receive(self, host: str) -> RtdeReceiveLink: ...
    def io(self, host: str) -> RtdeIOLink: ...


class URRtdeLinks:
    """The real ur_rtde interfaces (extra `ur`: ``pip install 'prompose-grasp[ur]'``).

    Args:
        receive_frequency_hz: RTDE output rate asked of the controller; -1 is the controller's maximum
            (500 Hz on e-Series, 125 Hz on CB3).
    """

    def __init__(self, receive_frequency_hz: float = -1.0):
        self.receive_frequency_hz = float(receive_frequency_hz)

    def control(self, host: str) -> RtdeControlLink:
        return require("rtde_control", extra="ur").RTDEControlInterface(host)

    def receive(self, host: str) -> RtdeReceiveLink:
        module = require("rtde_receive", extra="ur")
        return module.RTDEReceiveInterface(host, self.receive_frequency_hz, list(RECEIVE_VARIABLES))

    def io(self, host: str) -> RtdeIOLink:
        return require("rtde_io", extra="ur").RTDEIOInterface(host)


@dataclass(frozen=True)
class URRtdeConfig:
    """Settings of `URRtdeArm`.

    Attributes:
        servo_rate_hz: servoJ rate of `follow` [Hz]; the controller's cycle (500 on e-Series, 125 on CB3).
        lookahead_s: servoJ lookahead time [s], ur_rtde accepts [0.03, 0.2]; longer smooths, lags more.
        gain: servoJ proportional gain, ur_rtde accepts [100, 2000]; higher tracks tighter, may oscillate.
        poll_period_s: how often a running move is checked (progress, link, safety) [s].
        check_every_servo_steps: link and safety checks during `follow`, every this many servo cycles.
        stop_joint_decel_rad_s2: deceleration of stopJ [rad/s^2].
        stop_linear_decel_m_s2: deceleration of stopL and servoStop (ur_rtde's control script ends servo
            mode with stopl) [m/s^2].
        settle_timeout_s: after the last servoJ setpoint of `follow`, how long the arm may take to stand on
            it (within `reached_tol_rad`) while the setpoint is held; longer raises `MotionFailedError` [s].
        move_timeout_margin_s: a move not finished this long after its trapezoid time limit is stopped and
            reported (a controller that stopped answering progress) [s].
        start_timeout_s: a move the controller never reports running, with the arm not at its target after
            this long, is stopped and reported [s].
        reached_tol_rad, reached_tol_m: "at the target" for a move that finished between two polls: every
            joint within this [rad] (moveJ), the TCP within this [m] (moveL). The controller itself
            finishes within ~1e-4 rad / 0.1 mm.
        use_io: also open the IO link (for a suction gripper on the controller's digital outputs).
        model_tol_m, model_tol_rad: on connect, the controller's TCP pose must agree with the model's forward
            kinematics at the controller's joints within these, with the TCP just set; a wrong model (a UR5e
            model on a UR10e) or a TCP the controller did not take would otherwise put every move off. The
            nominal model and a factory-calibrated arm differ by a few millimetres, well inside 1 cm.
        tcp_sync_timeout_s: how long connect waits for a state package that carries the new TCP (RTDE
            publishes on its own cycle, so the first packages after setTcp may still show the old one) [s].
    """

    servo_rate_hz: float = 500.0
    lookahead_s: float = 0.1
    gain: float = 300.0
    poll_period_s: float = 0.01
    check_every_servo_steps: int = 10
    stop_joint_decel_rad_s2: float = 2.0
    stop_linear_decel_m_s2: float = 1.0
    move_timeout_margin_s: float = 10.0
    settle_timeout_s: float = 1.0
    start_timeout_s: float = 1.0
    reached_tol_rad: float = 1e-3
    reached_tol_m: float = 1e-3
    use_io: bool = False
    model_tol_m: float = 0.01
    model_tol_rad: float = 0.02
    tcp_sync_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not (0.03 <= self.lookahead_s <= 0.2):
            raise InvalidInputError(
                f"URRtdeConfig.lookahead_s must be in [0.03, 0.2] s, got {self.lookahead_s}"
            )
        if not (100.0 <= self.gain <= 2000.0):
            raise InvalidInputError(f"URRtdeConfig.gain must be in [100, 2000], got {self.gain}")
        for name in (
            "servo_rate_hz",
            "poll_period_s",
            "stop_joint_decel_rad_s2",
            "stop_linear_decel_m_s2",
            "move_timeout_margin_s",
            "settle_timeout_s",
            "start_timeout_s",
            "reached_tol_rad",
            "reached_tol_m",
            "model_tol_m",
            "model_tol_rad",
            "tcp_sync_timeout_s",
        ):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise InvalidInputError(f"URRtdeConfig.{name} must be finite and > 0, got {v}")
        if int(self.check_every_servo_steps) < 1:
            raise InvalidInputError("URRtdeConfig.check_every_servo_steps must be >= 1")


class URRtdeArm(Arm):
    """A UR arm over RTDE. See the module docstring for the safety behaviour.

    Args:
        host: the controller's IP address or host name.
        robot: the arm's `RobotModel` with the gripper's TCP offset (sent to the controller with setTcp on
            connect, so `getActualTCPPose` and `moveL` use the same TCP as the planner).
            Default: ur5e, no tool.
        validator_config: limits (default: the robot's own, `ValidatorConfig.for_robot`).
        config: `URRtdeConfig`.
        links: the link factory (default `URRtdeLinks()`, the real ur_rtde).
    """

    def __init__(
        self,
        host: str,
        robot: RobotModel | None = None,
        validator_config: ValidatorConfig | None = None,
        config: URRtdeConfig | None = None,
        links: RtdeLinks | None = None,
    ):
        if not isinstance(host, str) or not host.strip():
            raise InvalidInputError(f"host must be the controller's IP address or name, got {host!r}")
        self.host = host.strip()
        self.robot = robot or load_robot()
        self.validator = CommandValidator(
            validator_config or ValidatorConfig.for_robot(self.robot), fk_tcp=self.robot.fk_tcp
        )
        self.config = config or URRtdeConfig()
        self.links: RtdeLinks = links or URRtdeLinks()
        self._control: Any = None
        self._receive: Any = None
        self._io: Any = None
        self._stop_requested = threading.Event()
        self._motion: str | None = None  # "joint", "linear", "servo" while a command runs

    # ------------------------------------------------------------------------------------------ links
    def connect(self) -> None:
        """Open the receive, control (and IO) links and set the controller's TCP to the model's.

        Raises `DeviceNotConnectedError` (at once when nothing listens on port 30004) with what to check.
        """
        if self._connected:
            return
        try:
            self._receive = self.links.receive(self.host)
            self._control = self.links.control(self.host)
            if self.config.use_io:
                self._io = self.links.io(self.host)
        except RuntimeError as exc:
            self._close_links()
            raise DeviceNotConnectedError(
                f"could not connect to the UR controller at {self.host} (RTDE port {RTDE_PORT}): "
                f"{str(exc).strip()}. Check the cable and IP address, that the arm is powered on and "
                "initialised, and on e-Series arms that it is in Remote Control mode (pendant, top right)."
            ) from exc
        super().connect()
        self._stop_requested.clear()
        tcp = pose_vector_from_T(self.robot.T_flange_tcp).tolist()
        if not self._control.setTcp(tcp):
            self.disconnect()
            raise DeviceNotConnectedError(f"the controller at {self.host} refused setTcp({tcp})")
        self._check_model_agrees()
        logger.info("connected to UR at %s; TCP set to %s", self.host, np.round(tcp, 4).tolist())

    def _check_model_agrees(self) -> None:
        """Wait until the controller's TCP pose matches the model's FK at its joints (within
        `URRtdeConfig.model_tol_m` and `model_tol_rad`); disconnect and raise `DeviceNotConnectedError` when
        it does not within `tcp_sync_timeout_s`."""
        cfg = self.config
        deadline = time.monotonic() + cfg.tcp_sync_timeout_s
        while True:
            q = np.asarray(self._receive.getActualQ(), dtype=np.float64)
            T_ctrl = T_from_pose_vector(np.asarray(self._receive.getActualTCPPose(), dtype=np.float64))
            T_model = self.robot.fk_tcp(q)
            off_m = float(np.linalg.norm(T_ctrl[:3, 3] - T_model[:3, 3]))
            off_rad = rotation_angle(T_ctrl[:3, :3], T_model[:3, :3])
            if off_m <= cfg.model_tol_m and off_rad <= cfg.model_tol_rad:
                return
            if time.monotonic() > deadline:
                self.disconnect()
                raise DeviceNotConnectedError(
                    f"the UR controller at {self.host} reports its TCP {1000 * off_m:.0f} mm and "
                    f"{np.degrees(off_rad):.1f} deg from where the {self.robot.name} model puts it at the "
                    "same joints, with the TCP just set: check that the model is this arm's (ur3e, ur5e, "
                    "ur10e, ...) and that no program on the controller changes the TCP"
                )
            time.sleep(cfg.poll_period_s)

    def disconnect(self) -> None:
        """Stop any motion, end the controller script and close the links. Safe to call twice."""
        if self._control is not None and self._connected:
            if self._motion is not None:
                self._send_stop()
            try:
                self._control.stopScript()
            except RuntimeError as exc:
                logger.warning("stopScript failed while disconnecting: %s", exc)
        self._close_links()
        super().disconnect()

    def reconnect(self) -> None:
        """Resume after a `ConnectionLostError`, or after a safety stop that was cleared on the pendant.

        Only links that dropped are reopened: ur_rtde's `reconnect()` on a live control link opens a second
        RTDE connection whose input registers the controller refuses as IN_USE (the first still holds them),
        and on a live link its background reconnect races ours (seen against the controller emulation: a
        crash of the process). The controller ends the control script on a safety stop (and on a dashboard
        stop), so when it no longer runs it is uploaded again (`reuploadScript`) and waited for; then the
        TCP is set again. Raises the safety error while the stop is not cleared, `DeviceNotConnectedError`
        when the controller does not answer.
        """
        if self._control is None or self._receive is None:
            self.connect()
            return
        try:
            for link in (self._receive, self._control, self._io):
                if link is not None and not link.isConnected() and not link.reconnect():
                    raise RuntimeError(f"{type(link).__name__}.reconnect() returned False")
            self._check_safety("reconnect")
            if not self._control.isProgramRunning():
                self._control.reuploadScript()
                deadline = time.monotonic() + SCRIPT_START_TIMEOUT_S
                while not self._control.isProgramRunning():
                    if time.monotonic() > deadline:
                        raise RuntimeError(
                            f"the control script did not start within {SCRIPT_START_TIMEOUT_S:.0f} s of its "
                            "upload (is a program running on the pendant, or the arm not in Remote Control?)"
                        )
                    time.sleep(0.01)
        except RuntimeError as exc:
            raise DeviceNotConnectedError(
                f"could not reconnect to the UR controller at {self.host}: {exc}"
            ) from exc
        self._connected = True
        self._stop_requested.clear()
        tcp = pose_vector_from_T(self.robot.T_flange_tcp).tolist()
        if not self._control.setTcp(tcp):
            raise DeviceNotConnectedError(f"the controller at {self.host} refused setTcp({tcp}) on reconnect")

    def _close_links(self) -> None:
        for link in (self._control, self._receive, self._io):
            if link is not None:
                try:
                    link.disconnect()
                except RuntimeError as exc:
                    logger.warning("closing %s: %s", type(link).__name__, exc)
        self._control = self._receive = self._io = None

    @property
    def receive_link(self) -> RtdeReceiveLink:
        """The open receive link (the suction gripper reads its vacuum input through it)."""
        self._require()
        return self._receive

    @property
    def io_link(self) -> RtdeIOLink:
        """The open IO link (`URRtdeConfig(use_io=True)`)."""
        self._require()
        if self._io is None:
            raise DeviceNotConnectedError(
                "the IO link is not open: build the arm with URRtdeConfig(use_io=True)"
            )
        return self._io

    # ------------------------------------------------------------------------------------------ checks
    def _link_ok(self) -> bool:
        try:
            return bool(self._receive.isConnected()) and bool(self._control.isConnected())
        except RuntimeError:
            return False

    def _check(self, what: str) -> None:
        """Raise if a link dropped (after the stop path) or the controller is in a safety stop."""
        if not self._link_ok():
            self._lost(what)
        self._check_safety(what)

    def _explain_refusal(self, what: str) -> None:
        """The controller refused a command: raise the safety stop or lost link that explains it, if any.

        ur_rtde refuses as soon as its control link sees the program stopped, and a safety stop reaches the
        receive link a package or two later (seen against the controller emulation: a protective stop
        mid-stream read as a plain refusal), so the links get `LINK_VERDICT_S` to agree first.
        """
        deadline = time.monotonic() + LINK_VERDICT_S
        while True:
            self._check(what)
            if time.monotonic() > deadline:
                return
            time.sleep(0.005)

    def _check_safety(self, what: str) -> None:
        if self._receive.isEmergencyStopped():
            self._motion = None
            raise EmergencyStopError(
                f"{what}: the arm is emergency stopped; release the e-stop, re-enable the arm on the "
                "pendant, then reconnect()"
            )
        if self._receive.isProtectiveStopped():
            self._motion = None
            raise ProtectiveStopError(
                f"{what}: the arm is in a protective stop; find the cause, unlock it on the pendant, then "
                "reconnect()"
            )

    def _lost(self, what: str, cause: BaseException | None = None) -> None:
        """Connection-loss path: stop where the control link still answers, mark disconnected, raise."""
        logger.error("%s: link to the UR controller at %s lost (%s); stopping", what, self.host, cause)
        # A cut cable shows on both links within milliseconds, but each ur_rtde interface notices on its own
        # thread. A stop sent into a control link that is going down waits on the link's stale state for
        # ur_rtde's execution timeout (minutes; seen against the controller emulation when the receive link
        # noticed first), so give the control link a moment to report itself down first.
        deadline = time.monotonic() + LINK_VERDICT_S
        while time.monotonic() < deadline and self._control_up():
            time.sleep(0.005)
        self._send_stop()
        self._connected = False
        detail = f" ({cause})" if cause is not None else ""
        raise ConnectionLostError(
            f"{what}: the link to the UR controller at {self.host} was lost{detail}; a stop was sent if the "
            "control link still answered, otherwise the controller finishes the move it was given (it does "
            "not stop when its RTDE client goes). Check the arm, then reconnect()"
        ) from cause

    def _control_up(self) -> bool:
        try:
            return bool(self._control.isConnected())
        except RuntimeError:
            return False

    def _send_stop(self) -> None:
        motion, self._motion = self._motion, None
        c = self.config
        try:
            if not self._control_up():
                # Nothing can arrive over a dead link, and ur_rtde would wait for the stop's acknowledgement
                # on the link's last (stale) state until its execution timeout, minutes (seen against the
                # controller emulation), instead of failing.
                logger.error(
                    "the control link is down: no stop can be sent; the controller finishes its move"
                )
                return
            if motion == "servo":
                # ur_rtde's script ends servo mode with stopl: servoStop takes a tool deceleration.
                self._control.servoStop(c.stop_linear_decel_m_s2)
            elif motion == "linear":
                self._control.stopL(c.stop_linear_decel_m_s2, False)
            else:
                self._control.stopJ(c.stop_joint_decel_rad_s2, False)
        except RuntimeError as exc:  # the control link is gone too
            logger.warning("stop command could not be sent: %s", exc)

    # ------------------------------------------------------------------------------------------ state
    def joint_positions(self) -> np.ndarray:
        self._require()
        self._check_link_only("joint_positions")
        q = np.asarray(self._receive.getActualQ(), dtype=np.float64)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise ConnectionLostError(f"the controller reported joint positions {q.tolist()}")
        return q

    def tcp_pose(self) -> np.ndarray:
        """(4, 4) T_base_tcp from `getActualTCPPose` (x, y, z, rotation vector) with the model's TCP."""
        self._require()
        self._check_link_only("tcp_pose")
        return T_from_pose_vector(np.asarray(self._receive.getActualTCPPose(), dtype=np.float64))

    def _check_link_only(self, what: str) -> None:
        if not self._link_ok():
            self._lost(what)

    # ------------------------------------------------------------------------------------------ motion
    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        self._require()
        command = self.validator.validate_joint_move(q, speed, accel, q_current=self.joint_positions())
        self._check("move_joints")
        q_list = command.q.tolist()
        timeout_s = _trapezoid_time(
            float(np.max(np.abs(command.q - self.joint_positions()))),
            command.speed_rad_s,
            command.accel_rad_s2,
        )
        self._run_async(
            "move_joints",
            "joint",
            lambda: self._control.moveJ(q_list, command.speed_rad_s, command.accel_rad_s2, True),
            timeout_s,
            lambda: float(np.max(np.abs(self.joint_positions() - command.q))) <= self.config.reached_tol_rad,
        )
        return command

    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        command = self._linear(T_base_tcp, speed, accel, "move_linear")
        self._run_linear(command, "move_linear")
        return command

    @property
    def senses_contact(self) -> bool:
        return True

    def move_linear_until_contact(
        self, T_base_tcp: ArrayLike, speed: float, accel: float, max_force_n: float
    ) -> bool:
        """`move_linear`, stopped (stopL at `stop_linear_decel_m_s2`) at the first poll where the force at
        the tool (`getActualTCPForce`, the controller's estimate: an e-Series arm's built-in sensor, a CB3's
        joint currents) differs from its value before the move by more than `max_force_n` [N]: the
        difference leaves out the sensor's offset and the tool's own weight. True when the line was
        completed, False when it stopped on contact. The force is read every `poll_period_s`: at the
        approach speeds of a guarded move (a few cm/s) the arm travels a millimetre or two between reads."""
        limit = self.contact_force_limit(max_force_n)
        command = self._linear(T_base_tcp, speed, accel, "move_linear_until_contact")
        f0 = self._tool_force("move_linear_until_contact")
        felt: list[float] = []

        def touched() -> bool:
            f = float(np.linalg.norm(self._tool_force("move_linear_until_contact") - f0))
            if f > limit or not math.isfinite(f):  # an unreadable force is no guard: stop as on a touch
                felt.append(f)
            return bool(felt)

        if not np.all(np.isfinite(f0)):
            raise MotionFailedError(
                f"move_linear_until_contact: the tool force reads {np.round(f0, 1).tolist()} N: no guard can "
                "be kept on it; nothing was sent"
            )
        self._run_linear(command, "move_linear_until_contact", touched)
        if felt and not math.isfinite(felt[0]):
            self._send_stop()
            raise MotionFailedError(
                "move_linear_until_contact: the tool force stopped reading (not finite) during the move: "
                "stopped"
            )
        if not felt:
            return True
        self._send_stop()
        logger.info("guarded move stopped on contact: %.0f N at the tool (limit %g N)", felt[0], limit)
        return False

    def _tool_force(self, what: str) -> np.ndarray:
        """(3,) the force part of `getActualTCPForce` [N]."""
        try:
            return np.asarray(self._receive.getActualTCPForce(), dtype=np.float64)[:3]
        except RuntimeError as exc:
            self._lost(what, exc)
            raise  # not reached: `_lost` raises

    def _linear(self, T_base_tcp: ArrayLike, speed: float, accel: float, what: str) -> LinearCommand:
        """The validated straight line to `T_base_tcp`, its end configuration checked too."""
        self._require()
        command = self.validator.validate_linear_move(T_base_tcp, speed, accel)
        q_now = self.joint_positions()
        result = self.robot.ik(command.T_base_tcp, q_seed=q_now, frame="tcp")
        if not result.success:
            raise UnreachableError(f"{what} target not reachable: {result.message}")
        # The end configuration goes through the joint checks too (limits, step, workspace).
        self.validator.validate_configuration(result.q, q_now, f"{what} end configuration")
        self._check(what)
        return command

    def _run_linear(self, command: LinearCommand, what: str, until=None) -> None:
        """Send the validated line as an asynchronous moveL and watch it (`_run_async`)."""
        pose = pose_vector_from_T(command.T_base_tcp).tolist()
        distance = float(np.linalg.norm(command.T_base_tcp[:3, 3] - self.tcp_pose()[:3, 3]))
        timeout_s = _trapezoid_time(distance, command.speed_m_s, command.accel_m_s2)
        self._run_async(
            what,
            "linear",
            lambda: self._control.moveL(pose, command.speed_m_s, command.accel_m_s2, True),
            timeout_s,
            lambda: (
                float(np.linalg.norm(self.tcp_pose()[:3, 3] - command.T_base_tcp[:3, 3]))
                <= self.config.reached_tol_m
            ),
            until,
        )

    def _run_async(self, what: str, motion: str, send, nominal_s: float, reached, until=None) -> None:
        """Send an asynchronous move and watch it: progress, link, safety, stop requests.

        The move counts as finished when the progress register, having shown it running, reads -1 again,
        or when it reads -1 and `reached()` says the arm stands at the target (a short move may finish
        between two polls). A move that neither shows as running nor arrives within `start_timeout_s` is
        stopped and reported: the next command would otherwise be sent over a move still in progress.
        `until()`, when given, is asked at every poll while the move runs; True returns at once with the
        move still running (the caller stops it).
        """
        self._stop_requested.clear()
        self._motion = motion
        try:
            accepted = send()
        except RuntimeError as exc:  # ur_rtde raises when its link or the control script is gone
            self._lost(what, exc)
        if not accepted:
            self._motion = None
            self._explain_refusal(what)
            raise MotionFailedError(f"{what}: the controller did not accept the command")
        t_sent = time.monotonic()
        deadline = t_sent + nominal_s + self.config.move_timeout_margin_s
        started = False
        while True:
            if self._stop_requested.is_set():
                return
            try:
                running = self._control.getAsyncOperationProgress() >= 0
            except RuntimeError as exc:
                self._lost(what, exc)
            self._check(what)
            started = started or running
            if running and until is not None and until():
                return
            if not running and (started or reached()):
                self._motion = None
                return
            if not started and time.monotonic() - t_sent > self.config.start_timeout_s:
                self._send_stop()
                raise MotionFailedError(
                    f"{what}: the controller never reported the move running and the arm is not at the "
                    f"target after {self.config.start_timeout_s:.1f} s; stopped"
                )
            if time.monotonic() > deadline:
                self._send_stop()
                raise MotionFailedError(
                    f"{what}: the move did not finish within "
                    f"{nominal_s + self.config.move_timeout_margin_s:.1f} s; stopped"
                )
            time.sleep(self.config.poll_period_s)

    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        """Stream a timed trajectory with servoJ at `servo_rate_hz` (linear interpolation between waypoints,
        which stays within the validated waypoint steps and speeds), hold the last setpoint until the arm
        stands on it (`settle_timeout_s`), then servoStop."""
        self._require()
        q_now = self.joint_positions()
        sent = self.validator.validate_trajectory(trajectory, q_now)
        self._check("follow")
        c = self.config
        dt = 1.0 / c.servo_rate_hz
        t_knots = np.concatenate([[0.0], sent.t_s]) if sent.t_s[0] > 0 else sent.t_s
        q_knots = np.vstack([q_now, sent.q]) if sent.t_s[0] > 0 else sent.q
        n = int(np.ceil(t_knots[-1] / dt)) + 1
        times = np.minimum(np.arange(n) * dt, t_knots[-1])
        Q = np.stack([np.interp(times, t_knots, q_knots[:, j]) for j in range(6)], axis=1)
        self._stop_requested.clear()
        self._motion = "servo"
        for k, q in enumerate(Q):
            if self._stop_requested.is_set():
                return sent
            if k % c.check_every_servo_steps == 0:
                self._check("follow")
            self._servo_cycle(q, dt)
        if not self._settle(Q[-1]):
            return sent
        self._motion = None
        self._control.servoStop(c.stop_linear_decel_m_s2)
        self._check("follow")
        return sent

    def _settle(self, q_end: np.ndarray) -> bool:
        """Hold the last servo setpoint until the arm stands on it (False: `stop()` was called).

        The controller's servo filter trails the setpoints by about the lookahead time; servoStop right after
        the last one would stop the arm that far short of the trajectory's end (measured against the
        controller emulation: 6 mrad short after a 0.5 rad/s move with the 0.1 s default).
        """
        c = self.config
        dt = 1.0 / c.servo_rate_hz
        deadline = time.monotonic() + c.settle_timeout_s
        k = 0
        while float(np.max(np.abs(self.joint_positions() - q_end))) > c.reached_tol_rad:
            if self._stop_requested.is_set():
                return False
            if time.monotonic() > deadline:
                self._send_stop()
                raise MotionFailedError(
                    f"follow: the arm did not reach the trajectory's end within {c.settle_timeout_s:.1f} s "
                    f"of the last setpoint (tolerance {c.reached_tol_rad} rad); stopped"
                )
            if k % c.check_every_servo_steps == 0:
                self._check("follow")
            self._servo_cycle(q_end, dt)
            k += 1
        return True

    def _servo_cycle(self, q: np.ndarray, dt: float) -> None:
        """One servoJ setpoint in its control period; a refused one stops the arm (MotionFailedError)."""
        c = self.config
        t_cycle = self._control.initPeriod()
        try:
            ok = self._control.servoJ(q.tolist(), 0.0, 0.0, dt, c.lookahead_s, c.gain)
        except RuntimeError as exc:
            self._lost("follow", exc)
        if not ok:
            self._explain_refusal("follow")
            self._send_stop()
            raise MotionFailedError("follow: the controller refused a servoJ command; stopped")
        self._control.waitPeriod(t_cycle)

    def stop(self) -> None:
        """Decelerate to a stop now (stopJ / stopL / servoStop by what is running); callable from another
        thread while a move blocks, which then returns."""
        self._require()
        self._stop_requested.set()
        self._send_stop()


def _trapezoid_time(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest trapezoid (or triangle) profile over `distance` [s]."""
    if distance <= 0:
        return 0.0
    if distance <= speed * speed / accel:
        return 2.0 * float(np.sqrt(distance / accel))
    return distance / speed + speed / accel
