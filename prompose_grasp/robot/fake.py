"""`FakeArm` and `FakeGripper`: in-memory devices for tests and dry runs.

They behave like a real backend at the interface: every command goes through the `CommandValidator`, a refused
command leaves the state untouched, and what was sent is both returned and recorded in `sent`. Motions
complete instantly (no dynamics); `move_linear` uses the closed-form IK nearest the current configuration.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnreachableError
from prompose_grasp.robot.interfaces import Arm, Gripper, JointCommand, JointTrajectory, LinearCommand
from prompose_grasp.robot.model import RobotModel, load_robot
from prompose_grasp.robot.validator import CommandValidator, ValidatorConfig

logger = logging.getLogger(__name__)

#: A ready pose with the elbow up and the flange pointing down, away from every singularity [rad].
HOME_Q = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


class FakeArm(Arm):
    """An arm that is where it was last commanded. `sent` lists the validated commands in order."""

    def __init__(
        self,
        robot: RobotModel | None = None,
        q_initial: ArrayLike | None = None,
        validator_config: ValidatorConfig | None = None,
    ):
        self.robot = robot or load_robot()
        self.validator = CommandValidator(
            validator_config or ValidatorConfig.for_robot(self.robot), fk_tcp=self.robot.fk_tcp
        )
        q0 = HOME_Q if q_initial is None else np.asarray(q_initial, dtype=np.float64)
        if q0.shape != (6,) or not np.all(np.isfinite(q0)):
            raise InvalidInputError(f"q_initial must be a finite (6,) joint vector [rad], got {q0}")
        self._q = q0.copy()
        self.stopped = False
        self.sent: list[JointCommand | LinearCommand | JointTrajectory] = []

    def connect(self) -> None:
        super().connect()
        self.stopped = False

    def joint_positions(self) -> np.ndarray:
        self._require()
        return self._q.copy()

    def tcp_pose(self) -> np.ndarray:
        self._require()
        return self.robot.fk_tcp(self._q)

    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        self._require()
        command = self.validator.validate_joint_move(q, speed, accel, q_current=self._q)
        self.sent.append(command)
        self._q = command.q.copy()
        return command

    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        self._require()
        command = self.validator.validate_linear_move(T_base_tcp, speed, accel)
        result = self.robot.ik(command.T_base_tcp, q_seed=self._q, frame="tcp")
        if not result.success:
            raise UnreachableError(f"move_linear target not reachable: {result.message}")
        # The end configuration goes through the joint checks too (limits, step, workspace).
        self.validator.validate_configuration(result.q, self._q, "move_linear end configuration")
        self.sent.append(command)
        self._q = result.q.copy()
        return command

    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        self._require()
        sent = self.validator.validate_trajectory(trajectory, self._q)
        self.sent.append(sent)
        self._q = sent.q[-1].copy()
        return sent

    def stop(self) -> None:
        self._require()
        self.stopped = True


class FakeGripper(Gripper):
    """A parallel-jaw gripper; closing stops on an object of `object_width_m` (None: no object).

    Attributes:
        max_width_m: full opening [m].
        min_force_n, max_force_n: accepted grip-force range [N] (a Robotiq 2F-85 grips with 20-235 N).
    """

    def __init__(
        self,
        max_width_m: float = 0.085,
        object_width_m: float | None = None,
        min_force_n: float = 20.0,
        max_force_n: float = 235.0,
    ):
        if not max_width_m > 0:
            raise InvalidInputError(f"max_width_m must be > 0, got {max_width_m}")
        self.max_width_m = float(max_width_m)
        self.object_width_m = object_width_m
        self.min_force_n, self.max_force_n = float(min_force_n), float(max_force_n)
        self._width = self.max_width_m
        self._holding = False

    def open(self) -> None:
        self._require()
        self._width, self._holding = self.max_width_m, False

    def close(self, force: float) -> bool:
        self._require()
        if not (np.isfinite(force) and self.min_force_n <= force <= self.max_force_n):
            raise InvalidInputError(
                f"grip force must be within [{self.min_force_n}, {self.max_force_n}] N, got {force!r}"
            )
        obj = self.object_width_m
        if obj is not None and 0.0 < obj < self._width:
            self._width, self._holding = float(obj), True
        else:
            self._width, self._holding = 0.0, False
        return self._holding

    def grasp_detected(self) -> bool:
        self._require()
        return self._holding

    def width(self) -> float:
        self._require()
        return self._width
