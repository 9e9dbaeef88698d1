"""What a run can record for a person to step through afterwards (`Recorder`), and the recorder that records
nothing (`NULL_RECORDER`, the default everywhere).

The estimator (`ProMPose(recorder=...)`) and the pick loop (`PickAndPlace(recorder=...)`) call a recorder at
their stage points with the values they already hold; `prompose_grasp.viz.rerun_recorder.RerunRecorder`
writes them to a rerun recording (extra `viz`). The base class does nothing in every method, so a run without
a recorder pays one method call per stage and imports nothing; a recorder overrides what it wants.

This module imports nothing heavy: both perception and the pipeline use it.
"""

from __future__ import annotations

from typing import Any

__all__ = ["NULL_RECORDER", "Recorder"]


class Recorder:
    """Receives what a run sees and does, in the order it happens. Every method is a no-op here.

    The values are the library's own (duck-typed, so that this module imports no layer):

    - `frame(camera, frame)`: an `RGBDFrame` the loop captured (the robot's own depth removed), by camera
      name ("fixed", "wrist"); `T_base_cam` places it.
    - `grounding(frame, result)`: the grounder's `GroundingResult` on that frame (every candidate: mask, 2D
      box, score, measured attributes).
    - `estimates(frame, estimates)`: the estimator's `Estimate`s on that frame (camera frame).
    - `candidates(observations)`: the loop's candidates (`pipeline.observe.Observation`, in base), in the
      order they are tried; the first is the one acted on.
    - `grasps(plan)`: a `GraspPlan` (feasible grasps, best first; the rejected counts by reason).
    - `grasp_tried(grasp, index)`: a grasp about to be executed (its rank in the plan).
    - `attempt(record)`: an `AttemptRecord` (the grasp tried and how it ended).
    - `motion(name, t_s, q, tcp_xyz)`: an arm command as planned and sent: its joint waypoints q (N, 6)
      [rad] at the times t_s (N,) of `clock_s` (None for a straight TCP line, whose joints the arm's own
      IK chooses), and the TCP path it draws, tcp_xyz (M, 3) in base [m].
    - `arm_state(q, T_base_tcp)`: the arm's measured joints (6,) [rad] and the TCP pose (4, 4) from them.
    - `gripper(width_m, force_n, detected)`: a gripper reading or command (None: not known here).
    - `stage(stage, message)`: a progress event of the loop.
    - `outcome(outcome)`: the run's `PickOutcome`.
    - `begin_episode(name)` / `end_episode()`: one run; `close()`: nothing more will come.

    `enabled` is False for a recorder that records nothing: the loop then wraps no device to sample it.
    """

    enabled: bool = False

    def begin_episode(self, name: str) -> None:
        """A run starts (`name`: the command text)."""

    def end_episode(self) -> None:
        """The run ended (after `outcome`)."""

    def clock_s(self) -> float:
        """Seconds since the episode began (the recording's time line); 0 here."""
        return 0.0

    def frame(self, camera: str, frame: Any) -> None:
        """An `RGBDFrame` captured by the camera named `camera`."""

    def grounding(self, frame: Any, result: Any) -> None:
        """The `GroundingResult` of a prompt on `frame`."""

    def estimates(self, frame: Any, estimates: Any) -> None:
        """The `Estimate`s (camera frame) made on `frame`."""

    def candidates(self, observations: Any) -> None:
        """The loop's `Observation`s (base frame), in the order they are tried."""

    def grasps(self, plan: Any) -> None:
        """A `GraspPlan` on the current target."""

    def grasp_tried(self, grasp: Any, index: int) -> None:
        """The grasp about to run (`index`: its rank in the plan)."""

    def attempt(self, record: Any) -> None:
        """An `AttemptRecord`: the grasp tried and how it ended."""

    def motion(self, name: str, t_s: Any, q: Any, tcp_xyz: Any) -> None:
        """An arm command as planned: joint waypoints q (N, 6) [rad] at t_s (N,) [s of `clock_s`] or None,
        and its TCP path (M, 3) in base [m]."""

    def arm_state(self, q: Any, T_base_tcp: Any) -> None:
        """The arm's measured joints (6,) [rad] and TCP pose (4, 4) in base [m]."""

    def gripper(
        self, width_m: float | None = None, force_n: float | None = None, detected: bool | None = None
    ) -> None:
        """A gripper reading (jaw width [m], grasp detected) or command (force [N])."""

    def stage(self, stage: str, message: str) -> None:
        """A progress event of the loop."""

    def outcome(self, outcome: Any) -> None:
        """The run's `PickOutcome`."""

    def close(self) -> None:
        """Nothing more will be recorded (flush and release the sink)."""


#: The recorder that records nothing (the default of `ProMPose` and `PickAndPlace`).
NULL_RECORDER = Recorder()
