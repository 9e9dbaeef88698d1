"""The controller side of the UR emulation: robot state, the motion generator and ur_rtde's control script.

`EmulatedController` is what `ur_emulator.py` serves over the network. It holds the arm's joints, runs one
control cycle every 2 ms (an e-Series controller's 500 Hz), integrates the commanded motion kinematically on
the project's UR model (`load_robot`: the DH table the planner uses) and plays the part of the URScript
program ur_rtde uploads: a loop that reads a command id from ``input_int_register_0`` and its arguments from
the input registers, acknowledges on ``output_int_register_0`` (1 ready for a command, 2 done with it; the
"real-time" servoj only ever answers ready) and reports asynchronous moves on ``output_int_register_2``
(bit 15 running, bits 16-23 a write counter, bits 24-30 an operation id; a killed move reports finished).

The program is not interpreted: the emulator recognises ur_rtde's control script (register offset 0) when it
arrives on a script port and runs its register protocol for the command ids in `SUPPORTED_COMMANDS`. Any
other id ends the program the way a URScript runtime error would (ur_rtde then sees it not running), so a
test that strays outside the emulated subset fails instead of being acknowledged falsely.

Motion is kinematic. movej: the leading joint on a trapezoid of the given speed and acceleration, the others
in step. movel: the TCP on a straight line (orientation slerped) on a trapezoid of tool speed, joints by the
model's closed-form IK each cycle, seeded with the last (an IK failure stops the program). servoj: a
first-order lag with the lookahead time as time constant, within the joints' speed limits (a stand-in for the
controller's servo filter, which also lags its setpoints). stopj / stopl decelerate along the current path at
the given rate in that path's unit (rad/s^2 for movej, m/s^2 for movel); servo_stop (the script's stopl)
ramps the joint velocity down at the given rate. A safety stop halts the arm in the cycle it occurs (a real
arm brakes over some tens of milliseconds) and ends the program; the registers keep their last values.

Faults a test injects: `trigger_protective_stop`, `trigger_emergency_stop`, and a slow cycle
(`io_period_s`: RTDE packages are exchanged only that often; the motion keeps real time, clients see the
state late, their inputs are applied late, and later packages within one period overwrite earlier ones, as on
the real register interface).
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from prompose_grasp.geometry.se3 import T_from_pose_vector, pose_vector_from_T
from prompose_grasp.robot import load_robot

CYCLE_S = 0.002  # e-Series controller period (500 Hz)

# Command ids of ur_rtde 1.6's control script (its ``process_cmd``).
CMD_NONE = 0
CMD_MOVEJ = 1
CMD_MOVEJ_IK = 2
CMD_MOVEL = 3
CMD_MOVEL_FK = 4
CMD_SERVOJ = 11
CMD_SERVO_STOP = 16
CMD_SET_TCP = 29
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_IS_STEADY = 47
CMD_STOP_SCRIPT = 255

COMMAND_NAMES = {
    CMD_MOVEJ: "movej",
    CMD_MOVEJ_IK: "movej_ik",
    CMD_MOVEL: "movel",
    CMD_MOVEL_FK: "movel_fk",
    CMD_SERVOJ: "servoj",
    CMD_SERVO_STOP: "servo_stop",
    CMD_SET_TCP: "set_tcp",
    CMD_PROTECTIVE_STOP: "protective_stop",
    CMD_STOPL: "stopl",
    CMD_STOPJ: "stopj",
    CMD_IS_STEADY: "is_steady",
    CMD_STOP_SCRIPT: "stop_script",
}
SUPPORTED_COMMANDS = frozenset(COMMAND_NAMES)
#: the script acknowledges these "real-time" commands with "ready" at once, without a "done" handshake
REALTIME_COMMANDS = frozenset({CMD_SERVOJ})

# RTDE state values (Universal Robots' RTDE guide).
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_MODE_ROBOT_EMERGENCY_STOP = 7
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
SAFETY_BIT_NORMAL = 1 << 0
SAFETY_BIT_PROTECTIVE_STOPPED = 1 << 2
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED = 1 << 6
SAFETY_BIT_EMERGENCY_STOPPED = 1 << 7
ROBOT_STATUS_POWER_ON = 1 << 0
ROBOT_STATUS_PROGRAM_RUNNING = 1 << 1

#: markers of ur_rtde's control script (its main function and the register helpers it is built on)
CONTROL_SCRIPT_MARKERS = ("def rtde_control():", "read_input_integer_reg", "signal_async_operation_started")


def _trapezoid(length: float, speed: float, accel: float):
    """s(t) of a rest-to-rest trapezoid (triangle when `length` is short) over `length`; returns (s, T)."""
    if length * accel <= speed * speed:  # never reaches `speed`
        t_acc = float(np.sqrt(length / accel))
        v_top, t_flat = accel * t_acc, 0.0
    else:
        t_acc, v_top = speed / accel, speed
        t_flat = (length - speed * t_acc) / speed
    total = 2 * t_acc + t_flat

    def s_of(t: float) -> tuple[float, float]:
        if t <= 0:
            return 0.0, 0.0
        if t < t_acc:
            return 0.5 * accel * t * t, accel * t
        if t < t_acc + t_flat:
            return 0.5 * v_top * t_acc + v_top * (t - t_acc), v_top
        if t < total:
            r = total - t
            return length - 0.5 * accel * r * r, accel * r
        return length, 0.0

    return s_of, total


class _PathMove:
    """A movej / movel: the arm follows `q_at(s)` for s in [0, length] on a trapezoid speed profile; a stop
    decelerates along the same path (stopj / stopl / the end of a killed move thread)."""

    def __init__(self, kind: str, length: float, speed: float, accel: float, q_at):
        self.kind, self.length, self.q_at = kind, length, q_at
        self.s_of, self.duration_s = _trapezoid(length, speed, accel)
        self.t = 0.0
        self.s, self.sd = 0.0, 0.0
        self.stop_decel: float | None = None

    def step(self, dt: float) -> tuple[np.ndarray, bool]:
        if self.stop_decel is None:
            self.t += dt
            self.s, self.sd = self.s_of(self.t)
            done = self.t >= self.duration_s
        else:
            self.sd = max(0.0, self.sd - self.stop_decel * dt)
            self.s = min(self.length, self.s + self.sd * dt)
            done = self.sd == 0.0 or self.s >= self.length
        return self.q_at(self.s), done


class _ServoMotion:
    """servoj: tracks the latest target with a first-order lag whose time constant is the lookahead time,
    within the joints' speed limits. A stand-in for the controller's servo filter, not a model of it."""

    kind = "servo"

    def __init__(self, q: np.ndarray, max_speed: np.ndarray):
        self.q = q.copy()
        self.target = q.copy()
        self.lookahead_s = 0.1
        self.max_speed = max_speed
        self.qd = np.zeros(6)
        self.stop_decel: float | None = None

    def step(self, dt: float) -> tuple[np.ndarray, bool]:
        if self.stop_decel is None:
            qd = (self.target - self.q) / max(self.lookahead_s, dt)
            qd *= min(1.0, float(np.min(self.max_speed / np.maximum(np.abs(qd), 1e-12))))
        else:  # decelerate the current joint velocity to rest, the leading joint at `stop_decel`
            peak = float(np.max(np.abs(self.qd)))
            qd = self.qd * (max(0.0, peak - self.stop_decel * dt) / peak) if peak > 0 else self.qd
        self.qd = qd
        self.q = self.q + qd * dt
        return self.q, self.stop_decel is not None and not np.any(qd)


@dataclass
class ReceivedCommand:
    """One command the emulated script took from the input registers."""

    t_s: float  # controller time [s]
    cmd: int
    name: str
    args: tuple = ()


@dataclass
class _Registers:
    in_int: list = field(default_factory=lambda: [0] * 48)
    in_double: list = field(default_factory=lambda: [0.0] * 48)
    out_int: list = field(default_factory=lambda: [0] * 48)
    out_double: list = field(default_factory=lambda: [0.0] * 48)


class EmulatedController:
    """A UR controller reduced to what ur_rtde's control and receive interfaces use. Thread-safe.

    Args:
        robot: the arm's name in the project's registry (its DH table drives FK and IK here).
        q0: (6,) start joints [rad].
        unlock_delay_s: how long after a protective stop the dashboard refuses to unlock it (5 s on a
            real controller; tests shorten it).
    """

    def __init__(self, robot: str = "ur5e", q0=None, unlock_delay_s: float = 5.0):
        self.robot_name = robot
        self.model = load_robot(robot)
        self.q = np.asarray(q0 if q0 is not None else [0, -1.57, 1.57, -1.57, -1.57, 0], dtype=np.float64)
        self.qd = np.zeros(6)
        self.tcp_pose = [0.0] * 6
        self.lock = threading.RLock()
        self.reg = _Registers()
        self.t_s = 0.0
        self.motion: _PathMove | _ServoMotion | None = None
        self.t_motion_start = 0.0
        self.move_async = False  # the running path move was started by the script's move thread
        self.sync_busy = False  # a synchronous command holds the script's main loop until its motion ends
        self.program: str | None = None  # the loaded program's name while it runs
        self.program_error: str | None = None
        self.executing = False
        self.protective = False
        self.estop = False
        self.t_protective = 0.0
        self.unlock_delay_s = unlock_delay_s
        self.io_period_s = CYCLE_S
        self.commands: list[ReceivedCommand] = []
        #: (controller time [s], command id, arrival wall time [s, monotonic]) of every data package that
        #: carried a command id != 0: what reached the controller, whether or not a running script took it
        self.wire_commands: list[tuple[float, int, float]] = []
        self.faults: list[tuple[float, str]] = []
        self.programs: list[str] = []
        self._async_wr_count = 0
        self._async_op_id = 0
        self._pending_inputs: dict[str, float | int] = {}
        self._inputs_owner: dict[str, int] = {}

    def reset(self, q0) -> None:
        """Back to a powered, stopped arm at `q0` with empty logs (between tests sharing one controller)."""
        with self.lock:
            self.q, self.qd = np.asarray(q0, dtype=np.float64), np.zeros(6)
            self.motion, self.move_async, self.sync_busy = None, False, False
            self.program, self.program_error, self.executing = None, None, False
            self.protective = self.estop = False
            self.io_period_s = CYCLE_S
            self.tcp_pose = [0.0] * 6
            self.model = load_robot(self.robot_name)
            self.commands, self.wire_commands, self.faults, self.programs = [], [], [], []

    # ------------------------------------------------------------------------------------------ RTDE I/O
    def claim_inputs(self, client: int, names: list[str]) -> list[bool]:
        """Input recipe set-up: True for each register this client may write (False: IN_USE by another)."""
        with self.lock:
            free = [self._inputs_owner.get(n, client) == client for n in names]
            if all(free):
                for n in names:
                    self._inputs_owner[n] = client
            return free

    def release_inputs(self, client: int) -> None:
        with self.lock:
            self._inputs_owner = {n: s for n, s in self._inputs_owner.items() if s != client}

    def write_inputs(self, names: list[str], values: list) -> None:
        """A data package from a client: applied at the controller's next RTDE exchange."""
        with self.lock:
            self._pending_inputs.update(zip(names, values))
            cmd = self._pending_inputs.get("input_int_register_0", 0)
            if "input_int_register_0" in names and cmd != 0:
                self.wire_commands.append((self.t_s, int(cmd), time.monotonic()))

    def outputs(self) -> dict:
        """The output fields a client may ask for, at this instant."""
        with self.lock:
            T_base_tcp = self.model.fk_tcp(self.q)
            power = not self.estop
            safety_bits = SAFETY_BIT_NORMAL if not (self.protective or self.estop) else 0
            if self.protective:
                safety_bits |= SAFETY_BIT_PROTECTIVE_STOPPED
            if self.estop:
                safety_bits |= SAFETY_BIT_ROBOT_EMERGENCY_STOPPED | SAFETY_BIT_EMERGENCY_STOPPED
            safety_mode = (
                SAFETY_MODE_ROBOT_EMERGENCY_STOP
                if self.estop
                else SAFETY_MODE_PROTECTIVE_STOP
                if self.protective
                else SAFETY_MODE_NORMAL
            )
            out = {
                "timestamp": self.t_s,
                "actual_q": self.q.tolist(),
                "target_q": self.q.tolist(),
                "actual_qd": self.qd.tolist(),
                "target_qd": self.qd.tolist(),
                "actual_TCP_pose": pose_vector_from_T(T_base_tcp).tolist(),
                "target_TCP_pose": pose_vector_from_T(T_base_tcp).tolist(),
                "robot_mode": ROBOT_MODE_RUNNING if power else ROBOT_MODE_POWER_OFF,
                "safety_mode": safety_mode,
                "safety_status": safety_mode,
                "safety_status_bits": safety_bits,
                "robot_status_bits": (ROBOT_STATUS_POWER_ON if power else 0)
                | (ROBOT_STATUS_PROGRAM_RUNNING if self.program else 0),
                "runtime_state": RUNTIME_PLAYING if self.program else RUNTIME_STOPPED,
                "speed_scaling": 1.0,
                "target_speed_fraction": 1.0,
            }
            for i in range(48):
                out[f"output_int_register_{i}"] = self.reg.out_int[i]
                out[f"output_double_register_{i}"] = self.reg.out_double[i]
            return out

    def _apply_inputs(self) -> None:
        for name, value in self._pending_inputs.items():
            if name.startswith("input_int_register_"):
                self.reg.in_int[int(name.rsplit("_", 1)[1])] = int(value)
            elif name.startswith("input_double_register_"):
                self.reg.in_double[int(name.rsplit("_", 1)[1])] = float(value)
        self._pending_inputs.clear()

    # ------------------------------------------------------------------------------------------ programs
    def load_program(self, text: str) -> None:
        """A program arrived on a script port: it replaces the running one (as on the controller)."""
        with self.lock:
            self.programs.append(text)
            if self.program is not None:
                self._end_program("replaced by a new program")
            if self.protective or self.estop:
                return  # the controller refuses to start programs in a safety stop
            if not all(m in text for m in CONTROL_SCRIPT_MARKERS):
                self.program_error = "not ur_rtde's control script: the emulator runs only that one"
                return
            # ur_rtde injects the register offset after the marker comment (it lands on the next line).
            offset = re.search(r"reg_offset_int = (?:# int register offset\n)?\s*(\d+)", text)
            if offset is None or offset.group(1) != "0":
                self.program_error = "ur_rtde's upper register range (offset 24) is not emulated"
                return
            self.program, self.program_error, self.executing = "rtde_control", None, False
            self.reg.out_int[0] = 1  # signal_ready()
            self._async_progress(-1)  # reset_async_progress()

    def stop_program(self, reason: str) -> None:
        with self.lock:
            self._end_program(reason)

    def _end_program(self, reason: str) -> None:
        # Ending a program ends its motion: the controller brakes the arm along its path.
        if self.motion is not None and self.motion.stop_decel is None:
            self.motion.stop_decel = 4.0 if self.motion.kind != "movel" else 1.0
        self.program = None
        self.sync_busy = False
        self.program_error = reason

    # ------------------------------------------------------------------------------------------ faults
    def trigger_protective_stop(self) -> None:
        with self.lock:
            self._safety_stop("protective_stop")
            self.protective, self.t_protective = True, time.monotonic()

    def trigger_emergency_stop(self) -> None:
        with self.lock:
            self._safety_stop("emergency_stop")
            self.estop = True

    def note_fault(self, kind: str) -> None:
        with self.lock:
            self.faults.append((self.t_s, kind))

    def _safety_stop(self, kind: str) -> None:
        self.faults.append((self.t_s, kind))
        # A safety stop halts the arm and the program; the registers keep their last values (the async
        # progress register still says "running": the move thread was killed, not finished).
        self.motion, self.qd = None, np.zeros(6)
        self.program, self.sync_busy = None, False
        self.program_error = "safety stop"

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if not self.protective or time.monotonic() - self.t_protective < self.unlock_delay_s:
                return False
            self.protective = False
            return True

    def release_emergency_stop(self) -> None:
        """The e-stop released, the arm powered on and its brakes released (pendant work on a real arm)."""
        with self.lock:
            self.estop = False

    # ------------------------------------------------------------------------------------------ cycle
    def cycle(self, dt: float, exchange: bool) -> None:
        """One control cycle of `dt` seconds; `exchange`: RTDE inputs are read this cycle."""
        with self.lock:
            self.t_s += dt
            if exchange:
                self._apply_inputs()
                if self.program is not None:
                    self._script_tick()
            if self.motion is not None:
                q_prev = self.q
                try:
                    q, done = self.motion.step(dt)
                except _IKFailed as exc:  # a runtime error of the program: it stops, and so does the arm
                    self.motion, self.qd = None, np.zeros(6)
                    self._end_program(str(exc))
                    return
                self.q = np.asarray(q, dtype=np.float64)
                self.qd = (self.q - q_prev) / dt
                if done:
                    self._motion_done()

    def _motion_done(self) -> None:
        if self.move_async:
            self._async_progress(-1)
            self.move_async = False
        self.motion, self.qd = None, np.zeros(6)
        if self.sync_busy:  # a synchronous command (move or stop) returns now: "done"
            self.sync_busy = False
            self.reg.out_int[0] = 2

    def _script_tick(self) -> None:
        """One pass of the control script's main loop (between two ``sync()``)."""
        if self.sync_busy:
            return
        cmd = self.reg.in_int[0]
        if cmd == CMD_NONE:
            self.executing = False
            self.reg.out_int[0] = 1
        elif cmd in REALTIME_COMMANDS:
            self._process(cmd)
            self.reg.out_int[0] = 1
        elif not self.executing:
            self.executing = True
            self._process(cmd)
            if self.program is not None and not self.sync_busy:
                self.reg.out_int[0] = 2

    def _async_progress(self, value: int) -> None:
        self._async_wr_count = (self._async_wr_count + 1) % 128
        if value == 0:
            self._async_op_id = (self._async_op_id + 1) % 128
        reg = self._async_wr_count * 65536 + self._async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.reg.out_int[2] = reg

    def _log(self, cmd: int, *args) -> None:
        self.commands.append(ReceivedCommand(self.t_s, cmd, COMMAND_NAMES.get(cmd, "?"), args))

    def _process(self, cmd: int) -> None:
        d, i = self.reg.in_double, self.reg.in_int
        if cmd not in SUPPORTED_COMMANDS:
            self._log(cmd)
            self._end_program(f"command {cmd} is not emulated")
            return
        if cmd in (CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK):
            target, v, a, asynchronous = d[0:6], d[6], d[7], bool(i[1])
            self._log(cmd, tuple(target), v, a, asynchronous)
            try:
                self._start_move(cmd, np.asarray(target, dtype=np.float64), v, a, asynchronous)
            except _IKFailed as exc:
                self._end_program(str(exc))
        elif cmd == CMD_SERVOJ:
            # The script re-reads a real-time command every cycle until the next package replaces it; the
            # log keeps each setpoint once.
            args = (tuple(d[0:6]), d[8], d[9], d[10])
            if not (self.commands and self.commands[-1].cmd == cmd and self.commands[-1].args == args):
                self._log(cmd, *args)
            if not isinstance(self.motion, _ServoMotion) or self.motion.stop_decel is not None:
                self._kill_async_move()
                self.motion = _ServoMotion(self.q, self.model.max_joint_speed)
                self.t_motion_start = self.t_s
            self.motion.target = np.asarray(d[0:6], dtype=np.float64)
            self.motion.lookahead_s = float(d[9])
        elif cmd in (CMD_STOPJ, CMD_STOPL, CMD_SERVO_STOP):
            decel = float(d[0])
            self._log(cmd, decel, bool(i[1]) if cmd != CMD_SERVO_STOP else False)
            self._stop_motion(decel, synchronous=cmd == CMD_SERVO_STOP or not i[1])
        elif cmd == CMD_SET_TCP:
            self._log(cmd, tuple(d[0:6]))
            self.tcp_pose = list(d[0:6])
            self.model = load_robot(self.robot_name, tcp_offset=self.tcp_pose)
        elif cmd == CMD_IS_STEADY:
            self._log(cmd)
            self.reg.out_int[1] = int(self.motion is None)
        elif cmd == CMD_PROTECTIVE_STOP:
            self._log(cmd)
            self.trigger_protective_stop()
        elif cmd == CMD_STOP_SCRIPT:
            self._log(cmd)
            self._kill_async_move()
            self._end_program("stopped by stopScript")

    def _kill_async_move(self) -> None:
        # stop_async_move(): the move thread is killed and "finished" is signalled for it.
        if self.move_async:
            self._async_progress(-1)
            self.move_async = False

    def _stop_motion(self, decel: float, synchronous: bool) -> None:
        self._kill_async_move()
        if self.motion is None:
            return
        self.motion.stop_decel = max(decel, 1e-3)
        self.sync_busy = synchronous  # a synchronous stop answers "done" when the arm stands

    def _start_move(self, cmd: int, target: np.ndarray, v: float, a: float, asynchronous: bool) -> None:
        self._kill_async_move()
        q0 = self.q.copy()
        if cmd in (CMD_MOVEJ, CMD_MOVEJ_IK):
            q1 = target if cmd == CMD_MOVEJ else self._ik(T_from_pose_vector(target), q0)
            dq = q1 - q0
            length = float(np.max(np.abs(dq)))  # the leading joint moves at v, a; the others in step
            motion = _PathMove("movej", length, v, a, lambda s: q0 + dq * (s / length if length else 1.0))
        else:
            T0 = self.model.fk_tcp(q0)
            T1 = self.model.fk_tcp(target) if cmd == CMD_MOVEL_FK else T_from_pose_vector(target)
            motion = self._linear(T0, T1, q0, v, a)
        self.motion, self.t_motion_start = motion, self.t_s
        if asynchronous:
            self.move_async = True
            self._async_progress(0)
        else:
            self.sync_busy = True

    def _linear(self, T0: np.ndarray, T1: np.ndarray, q0: np.ndarray, v: float, a: float) -> _PathMove:
        """movel: the TCP on a straight line (orientation slerped) at tool speed v; a pure reorientation
        takes v as rad/s. Joints by IK each cycle, seeded with the previous cycle's (the nearest branch)."""
        p0, p1 = T0[:3, 3], T1[:3, 3]
        distance = float(np.linalg.norm(p1 - p0))
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]])))
        angle = float(
            np.linalg.norm(
                (Rotation.from_matrix(T0[:3, :3]).inv() * Rotation.from_matrix(T1[:3, :3])).as_rotvec()
            )
        )
        length = distance if distance > 1e-6 else angle
        seed = [q0]

        def q_at(s: float) -> np.ndarray:
            f = s / length if length > 0 else 1.0
            T = np.eye(4)
            T[:3, :3] = slerp([f]).as_matrix()[0]
            T[:3, 3] = p0 + f * (p1 - p0)
            seed[0] = self._ik(T, seed[0])
            return seed[0]

        return _PathMove("movel", length, v, a, q_at)

    def _ik(self, T_base_tcp: np.ndarray, seed: np.ndarray) -> np.ndarray:
        result = self.model.ik(T_base_tcp, q_seed=seed, frame="tcp")
        if not result.success:
            raise _IKFailed(f"inverse kinematics failed: {result.message}")
        return result.q

    def motion_time_s(self) -> float | None:
        """How long the current motion has run [s] (None: the arm stands)."""
        return None if self.motion is None else self.t_s - self.t_motion_start

    # ------------------------------------------------------------------------------------------ reports
    def snapshot(self) -> dict:
        """What a test reads: joints, flags, the commands the script took, the programs received."""
        with self.lock:
            return {
                "q": self.q.copy(),
                "tcp_pose": list(self.tcp_pose),
                "program": self.program,
                "program_error": self.program_error,
                "protective": self.protective,
                "estop": self.estop,
                "moving": self.motion is not None,
                "t_s": self.t_s,
                "commands": list(self.commands),
                "wire_commands": list(self.wire_commands),
                "faults": list(self.faults),
                "n_programs": len(self.programs),
            }


class _IKFailed(RuntimeError):
    pass
