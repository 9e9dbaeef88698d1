"""Stand-ins for the ur_rtde interfaces at our own boundary (`RtdeLinks`): they record every call in order.

`FakeControl` answers like RTDEControlInterface: commands return True, an asynchronous move reports
progress >= 0 for `moving_polls` polls and then -1 (finished). `FakeReceive` reports the state a test sets.
Hooks let a test cut the link or raise a safety stop at a chosen call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class CallLog(list):
    def names(self) -> list[str]:
        return [name for name, _ in self]


class FakeControl:
    def __init__(self, log: CallLog, moving_polls: int = 3):
        self.log = log
        self.moving_polls = moving_polls
        self.connected = True
        self.program_running = True
        self._polls_left = 0
        #: a `FakeReceive` that takes each move's target as the arm's new state (None: the state stays)
        self.receive: FakeReceive | None = None
        #: name -> callable run before answering (may raise RuntimeError, flip flags, ...)
        self.hooks: dict[str, Callable[[], Any]] = {}

    def _call(self, name: str, *args: Any) -> None:
        self.log.append((name, args))
        if name in self.hooks:
            self.hooks[name]()

    def setTcp(self, tcp_offset):
        self._call("setTcp", list(tcp_offset))
        return True

    def moveJ(self, q, speed, acceleration, asynchronous=False):
        self._call("moveJ", list(q), speed, acceleration, asynchronous)
        self._polls_left = self.moving_polls
        if self.receive is not None:
            self.receive.q = list(q)
        return True

    def moveL(self, pose, speed, acceleration, asynchronous=False):
        self._call("moveL", list(pose), speed, acceleration, asynchronous)
        self._polls_left = self.moving_polls
        if self.receive is not None:
            self.receive.tcp_pose = list(pose)
        return True

    def getAsyncOperationProgress(self):
        self._call("getAsyncOperationProgress")
        if self._polls_left > 0:
            self._polls_left -= 1
            return 0
        return -1

    def initPeriod(self):
        self._call("initPeriod")
        return 0

    def servoJ(self, q, speed, acceleration, time, lookahead_time, gain):
        self._call("servoJ", list(q), speed, acceleration, time, lookahead_time, gain)
        if self.receive is not None:  # the stand-in tracks setpoints without lag
            self.receive.q = list(q)
        return True

    def waitPeriod(self, t_cycle_start):
        self._call("waitPeriod")

    def servoStop(self, a=10.0):
        self._call("servoStop", a)
        return True

    def stopJ(self, a=2.0, asynchronous=False):
        self._call("stopJ", a, asynchronous)

    def stopL(self, a=10.0, asynchronous=False):
        self._call("stopL", a, asynchronous)

    def stopScript(self):
        self._call("stopScript")
        self.program_running = False

    def isProgramRunning(self):
        return self.program_running

    def reuploadScript(self):
        self._call("reuploadScript")
        self.program_running = True
        return True

    def isConnected(self):
        return self.connected

    def reconnect(self):
        self._call("reconnect")
        self.connected = True
        return True

    def disconnect(self):
        self._call("disconnect")
        self.connected = False


class FakeReceive:
    def __init__(self, q, tcp_pose):
        self.q = list(q)
        self.tcp_pose = list(tcp_pose)
        self.connected = True
        self.protective = False
        self.emergency = False
        self.inputs = 0
        #: [Fx, Fy, Fz, Tx, Ty, Tz] the controller's tool force estimate reports (a test sets it, or
        #: `force_at` gives it per call: a contact during a move)
        self.tcp_force = [0.0] * 6
        self.force_at: Callable[[int], list[float]] | None = None
        self.force_reads = 0

    def getActualQ(self):
        return list(self.q)

    def getActualTCPPose(self):
        return list(self.tcp_pose)

    def getActualTCPForce(self):
        self.force_reads += 1
        return list(self.tcp_force if self.force_at is None else self.force_at(self.force_reads))

    def isProtectiveStopped(self):
        return self.protective

    def isEmergencyStopped(self):
        return self.emergency

    def getDigitalInState(self, input_id):
        return bool(self.inputs >> input_id & 1)

    def isConnected(self):
        return self.connected

    def reconnect(self):
        self.connected = True
        return True

    def disconnect(self):
        self.connected = False


class FakeIO:
    def __init__(self, log: CallLog, on_output: Callable[[int, bool], None] | None = None):
        self.log = log
        self.on_output = on_output

    def setStandardDigitalOut(self, output_id, signal_level):
        self.log.append(("setStandardDigitalOut", (output_id, signal_level)))
        if self.on_output is not None:
            self.on_output(output_id, signal_level)
        return True

    def setToolDigitalOut(self, output_id, signal_level):
        self.log.append(("setToolDigitalOut", (output_id, signal_level)))
        return True

    def isConnected(self):
        return True

    def reconnect(self):
        return True

    def disconnect(self):
        self.log.append(("io.disconnect", ()))


class FakeLinks:
    """An `RtdeLinks` handing out the given fakes (or real links, for mixed tests)."""

    def __init__(self, control=None, receive=None, io=None):
        self._control, self._receive, self._io = control, receive, io
        self.opened: list[str] = []

    def control(self, host):
        self.opened.append("control")
        return self._control

    def receive(self, host):
        self.opened.append("receive")
        return self._receive

    def io(self, host):
        self.opened.append("io")
        return self._io
