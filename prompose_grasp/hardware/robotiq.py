"""`RobotiqGripper`: a Robotiq 2F-85 (or 2F-140) through the Robotiq URCap's text socket on the UR controller.

The URCap listens on TCP port 63352 of the controller and speaks one line per command:

| send | reply | meaning |
|---|---|---|
| ``SET ACT 1`` | ``ack`` | activate (the gripper opens and closes once to find its stroke) |
| ``SET GTO 1`` | ``ack`` | go to the requested position |
| ``SET POS n`` / ``SPE n`` / ``FOR n`` | ``ack`` | position / speed / force request, 0..255 |
| ``GET STA`` | ``STA n`` | 0 reset, 1 activating, 3 active |
| ``GET PRE`` | ``PRE n`` | echo of the position request (the gripper has taken it) |
| ``GET POS`` | ``POS n`` | current position, 0 open .. 255 closed |
| ``GET OBJ`` | ``OBJ n`` | 0 moving, 1 / 2 stopped on an object while opening / closing, 3 at the target |

Positions map linearly to the jaw opening: 0 -> `max_width_m`, 255 -> 0 (the 2F-85's 85 mm stroke; a real
gripper's calibrated range differs by a few counts, so widths are good to a few millimetres). Grip force maps
linearly from `force_range_n` (20..235 N for the 2F-85) to FOR 0..255.
"""

from __future__ import annotations

import logging
import socket
import time
from dataclasses import dataclass

import numpy as np

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError
from prompose_grasp.hardware.errors import ConnectionLostError, GripperError
from prompose_grasp.robot.interfaces import Gripper

__all__ = ["ROBOTIQ_PORT", "RobotiqConfig", "RobotiqGripper"]

logger = logging.getLogger(__name__)

#: The Robotiq URCap's socket port on the UR controller.
ROBOTIQ_PORT = 63352


@dataclass(frozen=True)
class RobotiqConfig:
    """Settings of `RobotiqGripper`.

    Attributes:
        max_width_m: opening at position 0 [m] (0.085 for the 2F-85, 0.140 for the 2F-140).
        force_range_n: grip force at FOR 0 and FOR 255 [N] (2F-85: 20..235 N).
        speed: SPE byte of every move, 0..255 (255: 150 mm/s on the 2F-85).
        timeout_s: socket reply timeout, and the longest a move or the activation may take [s].
        poll_period_s: status polling period while waiting [s].
    """

    max_width_m: float = 0.085
    force_range_n: tuple[float, float] = (20.0, 235.0)
    speed: int = 255
    timeout_s: float = 5.0
    poll_period_s: float = 0.02

    def __post_init__(self) -> None:
        if not (np.isfinite(self.max_width_m) and self.max_width_m > 0):
            raise InvalidInputError(f"RobotiqConfig.max_width_m must be > 0, got {self.max_width_m}")
        lo, hi = (float(v) for v in self.force_range_n)
        if not (0 <= lo < hi):
            raise InvalidInputError(
                f"RobotiqConfig.force_range_n must be 0 <= min < max [N], got {self.force_range_n}"
            )
        if not (0 <= int(self.speed) <= 255):
            raise InvalidInputError(f"RobotiqConfig.speed must be 0..255, got {self.speed}")
        if not (self.timeout_s > 0 and self.poll_period_s > 0):
            raise InvalidInputError("RobotiqConfig.timeout_s and poll_period_s must be > 0")


class RobotiqGripper(Gripper):
    """A Robotiq 2F gripper on the URCap socket (`host`: the UR controller).

    `connect()` opens the socket and activates the gripper if it is not active yet. Commands block until
    the jaws stop (`timeout_s`); a dropped socket raises `ConnectionLostError`, a refused command or an
    unexpected reply `GripperError`.
    """

    def __init__(self, host: str, port: int = ROBOTIQ_PORT, config: RobotiqConfig | None = None):
        if not isinstance(host, str) or not host.strip():
            raise InvalidInputError(f"host must be the UR controller's address, got {host!r}")
        self.host = host.strip()
        self.port = int(port)
        self.config = config or RobotiqConfig()
        self._sock: socket.socket | None = None
        self._buffer = b""

    # ------------------------------------------------------------------------------------------ socket
    def connect(self) -> None:
        if self._connected:
            return
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.config.timeout_s)
        except OSError as exc:
            raise DeviceNotConnectedError(
                f"could not connect to the Robotiq URCap at {self.host}:{self.port}: {exc}. Is the Robotiq "
                "URCap installed and the gripper plugged into the tool connector?"
            ) from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buffer = b""
        super().connect()
        try:
            self.activate()
        except Exception:
            self.disconnect()
            raise

    def disconnect(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
        self._sock = None
        super().disconnect()

    def _lost(self, what: str, exc: BaseException | None = None) -> None:
        self.disconnect()
        raise ConnectionLostError(f"Robotiq gripper at {self.host}:{self.port}: {what}") from exc

    def _exchange(self, line: str) -> str:
        """Send one command line and return the reply line (without the newline)."""
        self._require()
        assert self._sock is not None
        try:
            self._sock.sendall(line.encode("ascii") + b"\n")
            while b"\n" not in self._buffer:
                chunk = self._sock.recv(1024)
                if not chunk:
                    self._lost(f"the socket closed after {line!r}")
                self._buffer += chunk
        except TimeoutError as exc:
            self._lost(f"no reply to {line!r} within {self.config.timeout_s} s", exc)
        except OSError as exc:
            self._lost(f"socket error after {line!r}: {exc}", exc)
        reply, self._buffer = self._buffer.split(b"\n", 1)
        return reply.decode("ascii", errors="replace").strip()

    def _set(self, var: str, value: int) -> None:
        reply = self._exchange(f"SET {var} {int(value)}")
        if reply != "ack":
            raise GripperError(f"Robotiq refused 'SET {var} {int(value)}' (reply {reply!r}, expected 'ack')")

    def _get(self, var: str) -> int:
        reply = self._exchange(f"GET {var}")
        parts = reply.split()
        if len(parts) != 2 or parts[0] != var or not parts[1].lstrip("-").isdigit():
            raise GripperError(f"unexpected Robotiq reply to 'GET {var}': {reply!r} (expected '{var} <int>')")
        return int(parts[1])

    def _wait(self, what: str, done) -> int:
        deadline = time.monotonic() + self.config.timeout_s
        while True:
            value = done()
            if value is not None:
                return value
            if time.monotonic() > deadline:
                raise GripperError(f"Robotiq: {what} did not finish within {self.config.timeout_s} s")
            time.sleep(self.config.poll_period_s)

    # ------------------------------------------------------------------------------------------ commands
    def activate(self) -> None:
        """Activate (if not active) and enable motion (GTO 1)."""
        if self._get("STA") != 3:
            self._set("ACT", 1)
            self._wait("activation", lambda: 3 if self._get("STA") == 3 else None)
        self._set("GTO", 1)

    def move_to(self, position: int, force_byte: int | None = None) -> int:
        """Go to position 0..255 (0 open) with FOR `force_byte`; blocks until the jaws stop. Returns OBJ."""
        self._require()
        position = int(position)
        if not 0 <= position <= 255:
            raise InvalidInputError(f"Robotiq position must be 0..255, got {position}")
        self._set("SPE", self.config.speed)
        if force_byte is not None:
            self._set("FOR", force_byte)
        self._set("POS", position)
        self._set("GTO", 1)
        # The request echo (PRE) tells the gripper took the new target; only then is OBJ about this move.
        self._wait("the position request", lambda: 1 if self._get("PRE") == position else None)
        return self._wait("the move", lambda: obj if (obj := self._get("OBJ")) != 0 else None)

    def force_byte(self, force_n: float) -> int:
        """FOR byte of a grip force [N] within `force_range_n` (linear)."""
        lo, hi = self.config.force_range_n
        if not (np.isfinite(force_n) and lo <= force_n <= hi):
            raise InvalidInputError(f"grip force must be within [{lo}, {hi}] N, got {force_n!r}")
        return round(255.0 * (float(force_n) - lo) / (hi - lo))

    def width_of(self, position: int) -> float:
        """Jaw opening [m] at a position 0..255 (linear: 0 -> max_width_m, 255 -> 0)."""
        return self.config.max_width_m * (255 - min(max(int(position), 0), 255)) / 255.0

    def open(self) -> None:
        self.move_to(0)

    def close(self, force: float) -> bool:
        obj = self.move_to(255, self.force_byte(force))
        return obj == 2

    def grasp_detected(self) -> bool:
        """True when the jaws stopped on an object (OBJ 1 or 2)."""
        return self._get("OBJ") in (1, 2)

    def width(self) -> float:
        return self.width_of(self._get("POS"))
