"""The estimator seam of the loop: what it asks of an estimator (`Estimator`) and of each estimate it returns
(`ObjectEstimate`). `ProMPose` and its `perception.estimate.Estimate` are one; a test's oracle is another."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Protocol

from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.grounding import SupportPlane
from prompose_grasp.perception.priors import ShapePrior
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["Estimator", "ObjectEstimate"]


class ObjectEstimate(Protocol):
    """One object's estimate in one frame, as the loop reads it: `pose` (`Pose9D`, camera frame), `prior`
    (its `name` and `symmetry`) and `support_plane` (camera frame, or None). The loop also reads, where an
    estimate has them (`perception.estimate.Estimate` does): `score` (1 without one), `probability` and
    `contenders` (not judged without them), `mask`, `mesh_cam`, `surface_cam` and `attributes`."""

    @property
    def pose(self) -> Pose9D: ...

    @property
    def prior(self) -> ShapePrior: ...

    @property
    def support_plane(self) -> SupportPlane | None: ...


class Estimator(Protocol):
    """The best match of a prompt in a frame, and estimates frame after frame over a sequence. One with
    `estimate_all(frame, prompt, max_objects=, min_score_ratio=)` also gives the alternative candidates
    (`PickConfig.candidates`)."""

    def estimate(self, frame: RGBDFrame, prompt: str) -> ObjectEstimate: ...

    def track(self, frames: Iterable[RGBDFrame], prompt: str) -> Iterator[ObjectEstimate]: ...
