"""What one run of the loop has seen and done so far (`RunRecord`), the typed early end of a run (`Abort`),
and stage timing (`RunRecord.timed`).

`RunRecord` becomes the `PickOutcome` at the end of the run; nothing in it outlives the run.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from prompose_grasp.grasp.place import PlacePose
from prompose_grasp.grasp.types import Grasp, ObjectModel
from prompose_grasp.pipeline.outcome import AttemptRecord, Reason
from prompose_grasp.pipeline.seams import ObjectEstimate
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["STAGE_KEYS", "Abort", "Grip", "RunRecord"]

#: The stages whose wall time a run reports (`PickOutcome.timings_s`, plus "total").
STAGE_KEYS = ("observe", "estimate", "plan", "execute", "verify")


class Abort(Exception):
    """Ends a run with a typed reason (internal; never escapes `PickAndPlace.run`).

    `estimates` (camera frame of `T_base_cam`) go into the outcome ("ambiguous": the contenders);
    "wrong_object" says where the object put back stands (`held_at`) and where the one that fits better does
    (`retry_at`), in base [m]. `judged`: a "not_found" the grounder decided on the candidates it saw (nothing
    fits the words), not an empty frame."""

    def __init__(
        self,
        reason: Reason,
        message: str,
        estimates: Sequence[ObjectEstimate] = (),
        T_base_cam: np.ndarray | None = None,
        held_at: np.ndarray | None = None,
        retry_at: np.ndarray | None = None,
        judged: bool = False,
    ):
        super().__init__(message)
        self.judged = judged
        self.reason: Reason = reason
        self.message = message
        self.estimates = tuple(estimates)
        self.T_base_cam = T_base_cam
        self.held_at = held_at
        self.retry_at = retry_at


@dataclass
class Grip:
    """What the loop last told the gripper, for the stop path after a device fault: `closed` from the first
    close command on (a fault mid-close leaves the jaws closing) until it opens; `lifted` once an arm motion
    started while closed (the object may be off its support, and opening would drop it)."""

    closed: bool = False
    lifted: bool = False


@dataclass(eq=False)
class RunRecord:
    """One run's record.

    Attributes:
        t_start: `time.perf_counter()` at the start [s].
        timings_s: wall time per stage (`STAGE_KEYS`) [s].
        estimates, T_base_cams: every estimate the run acted on, in order, with its camera's pose in base.
        attempts: one record per grasp tried.
        grasp: the grasp that held (the last object's); place: its place pose (place commands).
        objects_done: objects picked (and placed) so far.
        placed: what this run put down, as boxes in base (obstacles for the next place).
        grip: what the gripper was last told (`Grip`).
        camera_modes: each camera's image size and intrinsics at its first frame of the run, by `id`.
        last_raw_frame: the last frame captured, the robot's own depth readings kept.
    """

    t_start: float = field(default_factory=time.perf_counter)
    timings_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGE_KEYS, 0.0))
    estimates: list[ObjectEstimate] = field(default_factory=list)
    T_base_cams: list[np.ndarray] = field(default_factory=list)
    attempts: list[AttemptRecord] = field(default_factory=list)
    grasp: Grasp | None = None
    place: PlacePose | None = None
    objects_done: int = 0
    placed: list[ObjectModel] = field(default_factory=list)
    grip: Grip = field(default_factory=Grip)
    camera_modes: dict[int, tuple[float, ...]] = field(default_factory=dict)
    last_raw_frame: RGBDFrame | None = None

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        """Add the wall time of the `with` block to `timings_s[stage]`, also when it raises."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[stage] += time.perf_counter() - t0

    def acted_on(self, estimate: ObjectEstimate, T_base_cam: np.ndarray | None) -> None:
        """Note an estimate the run acts on (it goes into the outcome's `estimates`)."""
        self.estimates.append(estimate)
        self.T_base_cams.append(np.asarray(T_base_cam, dtype=np.float64))

    def check_time(self, timeout_s: float) -> None:
        """ "timeout" once the run has taken more than `timeout_s` [s] (checked between stages)."""
        elapsed = time.perf_counter() - self.t_start
        if elapsed > timeout_s:
            raise Abort("timeout", f"{elapsed:.1f} s exceeds the {timeout_s:.1f} s budget")
