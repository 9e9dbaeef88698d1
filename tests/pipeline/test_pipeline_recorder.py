"""The loop's recorder seam on fakes (no rerun): a run reports its stages to the `Recorder` in order, the arm
is sampled while its commands run, and without a recorder no device is wrapped.

The estimator is an oracle stub (named so): a fixed box, so the test is about what the loop records, not
about perception.
"""

from __future__ import annotations

import inspect
import time

import numpy as np
import pytest
from test_pipeline_pick_faults import JAW, PICK, ROBOT, Camera, OracleEstimator

from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.pipeline.recording import ObservedArm
from prompose_grasp.recorder import NULL_RECORDER, Recorder
from prompose_grasp.robot import FakeArm, FakeGripper
from prompose_grasp.robot.interfaces import JointCommand


class Collecting(Recorder):
    """Keeps every call: (method, arguments)."""

    enabled = True

    def __init__(self):
        self.calls: list[tuple[str, tuple]] = []
        self.t0 = time.perf_counter()

    def clock_s(self) -> float:
        return time.perf_counter() - self.t0

    def __getattribute__(self, name: str):
        attr = object.__getattribute__(self, name)
        if name in ("calls", "t0", "clock_s", "enabled", "names", "of") or not callable(attr):
            return attr

        def keep(*args, **kw):  # the arguments in the signature's order, defaults filled in
            bound = inspect.signature(attr).bind(*args, **kw)
            bound.apply_defaults()
            self.calls.append((name, tuple(bound.arguments.values())))

        return keep

    def names(self) -> list[str]:
        return [n for n, _ in self.calls]

    def of(self, name: str) -> list[tuple]:
        return [a for n, a in self.calls if n == name]


def _run(recorder: Recorder | None):
    events: list = []
    cfg = PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=2)
    with FakeArm(ROBOT) as arm, FakeGripper(object_width_m=0.05) as gripper:
        pnp = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=cfg,
            on_event=events.append, recorder=recorder,
        )  # fmt: skip
        outcome = pnp.run(PICK)
        sent = list(arm.sent)
    return pnp, outcome, events, sent


def test_a_run_records_its_stages_in_order():
    rec = Collecting()
    pnp, outcome, events, sent = _run(rec)
    assert outcome.success, outcome.message
    names = rec.names()
    assert names[0] == "begin_episode" and names[-2:] == ["outcome", "end_episode"]
    assert rec.of("begin_episode")[0] == ("pick up the box",)
    assert rec.of("outcome")[0][0] is outcome
    # the stages in the order they ran: a frame, the candidates, a plan, the grasp tried, its attempt
    order = [names.index(n) for n in ("frame", "candidates", "grasps", "grasp_tried", "attempt")]
    assert order == sorted(order)
    assert [c for c, _ in rec.of("frame")] == ["fixed"]
    assert rec.of("attempt")[0][0] is outcome.attempts[0]
    # every progress event went to the recorder too
    assert [s for s, _ in rec.of("stage")] == [e.stage for e in events]
    # every arm command the loop sent is recorded, once, as planned: a joint move from where the arm stood
    # to its target; each ends with at least the sampler's last reading
    motions = rec.of("motion")
    assert len(motions) == len(sent) >= 3  # pre-grasp, approach, lift
    for (name, t_s, q, tcp), command in zip(motions, sent):
        assert np.asarray(tcp).shape[1] == 3
        if isinstance(command, JointCommand):
            assert name == "move_joints" and np.allclose(q[-1], command.q) and t_s[0] <= t_s[-1]
    assert len(rec.of("arm_state")) >= len(sent)
    # the gripper: the close command's force, then the width it closed to
    forces = [f for _, f, _ in rec.of("gripper") if f]
    assert forces and forces[0] == JAW.holding_force_n(pnp.config.grip_force_n)
    assert any(w == pytest.approx(0.05) for w, _, _ in rec.of("gripper") if w is not None)


def test_without_a_recorder_no_device_is_wrapped():
    pnp, outcome, _, _ = _run(None)
    assert outcome.success and pnp.loop.recorder is NULL_RECORDER
    assert isinstance(pnp.arm, FakeArm) and not isinstance(pnp.arm, ObservedArm)


class SlowArm(FakeArm):
    """A FakeArm whose joint moves take `duration_s` of wall time, the joints reading the straight line
    between start and target meanwhile (as a real arm's would)."""

    def __init__(self, duration_s: float):
        super().__init__(ROBOT)
        self.duration_s = duration_s
        self._move: tuple[float, np.ndarray, np.ndarray] | None = None

    def joint_positions(self) -> np.ndarray:
        if self._move is None:
            return super().joint_positions()
        t0, q0, q1 = self._move
        s = min(1.0, (time.perf_counter() - t0) / self.duration_s)
        return q0 + s * (q1 - q0)

    def move_joints(self, q, speed, accel):
        q0 = super().joint_positions()
        self._move = (time.perf_counter(), q0, np.asarray(q, dtype=np.float64))
        time.sleep(self.duration_s)
        self._move = None
        return super().move_joints(q, speed, accel)


def test_the_arm_is_sampled_while_a_command_runs():
    rec = Collecting()
    with SlowArm(duration_s=0.5) as slow:
        arm = ObservedArm(slow, ROBOT, rec, sample_hz=30.0)
        q0 = arm.joint_positions()
        q1 = q0 + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
        arm.move_joints(q1, 1.0, 1.0)
    states = rec.of("arm_state")
    # 0.5 s at 30 Hz is 15 samples; a loaded 2-core machine delays the sampler's wake-ups, so ask for 5
    assert len(states) >= 5
    pan = np.array([q[0] for q, _ in states])
    # measured along the way: some samples strictly between the start and the target, in order
    assert np.any((pan > q0[0] + 0.01) & (pan < q1[0] - 0.01))
    assert np.all(np.diff(pan) >= -1e-12) and pan[-1] == pytest.approx(q1[0])
    # the TCP of each sample is the model's forward kinematics of its joints
    q, T = states[len(states) // 2]
    assert np.allclose(T, ROBOT.fk_tcp(q))
    ((name, t_s, q_planned, _),) = rec.of("motion")
    assert name == "move_joints" and np.allclose(q_planned, [q0, q1])
    assert t_s[1] - t_s[0] >= 0.5  # drawn over the wall time the move took
