"""`IOSuctionGripper`: a vacuum gripper switched by a controller digital output, sensed by a digital input.

The vacuum generator's valve hangs on a standard (or tool) digital output of the UR controller and its vacuum
switch on a standard digital input; both go through the arm's RTDE links (`URRtdeArm` built with
`URRtdeConfig(use_io=True)`): outputs with `RTDEIOInterface.setStandardDigitalOut` / `setToolDigitalOut`,
the input with `RTDEReceiveInterface.getDigitalInState`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from prompose_grasp.errors import DeviceNotConnectedError, InvalidInputError
from prompose_grasp.hardware.errors import GripperError
from prompose_grasp.robot.interfaces import Gripper

__all__ = ["IOSuctionGripper", "SuctionIOConfig"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SuctionIOConfig:
    """Wiring and timing of the suction gripper.

    Attributes:
        vacuum_output: digital output that opens the vacuum valve (0..7).
        tool_output: `vacuum_output` is a tool output (0..1) instead of a standard one.
        vacuum_input: standard digital input of the vacuum switch (0..7); high = vacuum established.
        blow_off_output: optional output pulsed on release to drop the part at once (None: no blow-off).
        blow_off_s: length of that pulse [s].
        seal_timeout_s: how long `close` waits for the vacuum switch [s].
        poll_period_s: input polling period [s].
    """

    vacuum_output: int = 0
    tool_output: bool = False
    vacuum_input: int = 0
    blow_off_output: int | None = None
    blow_off_s: float = 0.2
    seal_timeout_s: float = 1.0
    poll_period_s: float = 0.01

    def __post_init__(self) -> None:
        top = 1 if self.tool_output else 7
        if not 0 <= int(self.vacuum_output) <= top:
            raise InvalidInputError(
                f"SuctionIOConfig.vacuum_output must be 0..{top}, got {self.vacuum_output}"
            )
        if not 0 <= int(self.vacuum_input) <= 7:
            raise InvalidInputError(f"SuctionIOConfig.vacuum_input must be 0..7, got {self.vacuum_input}")
        if self.blow_off_output is not None and not 0 <= int(self.blow_off_output) <= top:
            raise InvalidInputError(f"SuctionIOConfig.blow_off_output must be 0..{top} or None")
        if not (self.seal_timeout_s > 0 and self.poll_period_s > 0 and self.blow_off_s > 0):
            raise InvalidInputError("SuctionIOConfig times must be > 0")


class IOSuctionGripper(Gripper):
    """Vacuum on a digital output, vacuum switch on a digital input, through a connected `URRtdeArm`.

    `close(force)` switches the vacuum on and waits up to `seal_timeout_s` for the switch; `force` is checked
    for being a finite positive number only (a vacuum cup's holding force is set by the cup and the supply,
    not by a command).
    """

    def __init__(self, arm, config: SuctionIOConfig | None = None):
        self.arm = arm
        self.config = config or SuctionIOConfig()

    def connect(self) -> None:
        if not getattr(self.arm, "is_connected", False):
            raise DeviceNotConnectedError("IOSuctionGripper needs its arm connected first (with use_io=True)")
        self.arm.io_link  # noqa: B018 - raises when the arm has no IO link
        super().connect()

    def _output(self, pin: int, level: bool) -> None:
        io = self.arm.io_link
        c = self.config
        ok = io.setToolDigitalOut(pin, level) if c.tool_output else io.setStandardDigitalOut(pin, level)
        if not ok:
            raise GripperError(f"the controller refused to set digital output {pin} to {level}")

    def open(self) -> None:
        self._require()
        c = self.config
        self._output(c.vacuum_output, False)
        if c.blow_off_output is not None:
            self._output(c.blow_off_output, True)
            time.sleep(c.blow_off_s)
            self._output(c.blow_off_output, False)

    def close(self, force: float) -> bool:
        self._require()
        if not (isinstance(force, (int, float)) and force > 0 and force == force and force != float("inf")):
            raise InvalidInputError(f"force must be a finite number > 0 [N], got {force!r}")
        self._output(self.config.vacuum_output, True)
        deadline = time.monotonic() + self.config.seal_timeout_s
        while time.monotonic() < deadline:
            if self.grasp_detected():
                return True
            time.sleep(self.config.poll_period_s)
        held = self.grasp_detected()
        if not held:
            logger.info("no vacuum within %.2f s: nothing sealed", self.config.seal_timeout_s)
        return held

    def grasp_detected(self) -> bool:
        self._require()
        return bool(self.arm.receive_link.getDigitalInState(self.config.vacuum_input))

    def width(self) -> float:
        self._require()
        return 0.0
