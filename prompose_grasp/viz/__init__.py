"""Recordings a person steps through afterwards: `RerunRecorder` (extra `viz`, rerun-sdk) records a run of
the estimator or the pick loop; `RerunTarget.parse` reads the `--rerun FILE.rrd | spawn | connect [URL]`
words of the command lines. rerun itself is imported only by `viz.rerun_recorder`, when a recorder opens.

```
from prompose_grasp.viz import RerunRecorder, RerunTarget
recorder = RerunRecorder.open(RerunTarget.parse(["episode.rrd"]))
outcome = PickAndPlace.for_cell(cell, ProMPose.default(recorder=recorder), recorder=recorder).run(text)
recorder.close()
```
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to
    from prompose_grasp.viz.rerun_recorder import RerunRecorder
    from prompose_grasp.viz.target import RerunTarget

__all__ = ["RerunRecorder", "RerunTarget"]

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.viz.rerun_recorder": ("RerunRecorder",),
        "prompose_grasp.viz.target": ("RerunTarget",),
    },
)
