"""Recorded sim episodes into one LeRobot dataset: `python -m sim bench-pick ... --record DIR` and
`python -m sim pick ... --record DIR` (`sim.recording` samples, `sim.lerobot_dataset` writes).

Each episode becomes one LeRobot episode: its command is the task; `observation.state`, `action` and the
`observation.images.front` / `.wrist` videos are the recording's (`sim.recording`); the episodes meta parquet
carries, next to lerobot's own columns, `success` (bool, the benchmark's ground-truth verdict), `reason` (its
accounting reason: "success", a `PickOutcome` reason, "wrong_object_success", ...), `seed` (int) and `scene`
(the scene file). An episode that crashed (an exception, no outcome) is not written.
"""

from __future__ import annotations

import atexit
import logging
from pathlib import Path

from prompose_grasp.errors import InvalidInputError
from sim.recording import RecordConfig, RecordedEpisode, lerobot_features

__all__ = ["EpisodeSink"]

log = logging.getLogger(__name__)


class EpisodeSink:
    """A new LeRobot dataset at `root` that recorded episodes are added to.

    The dataset is created at the first episode (its cameras fix the video features); every later episode
    must have the same cameras. `close()` finishes the videos and meta files; it also runs at interpreter
    exit, so a run stopped with Ctrl-C leaves a readable dataset of the episodes written.
    """

    def __init__(self, root: str | Path, config: RecordConfig | None = None):
        self.root = Path(root)
        if self.root.exists() and (not self.root.is_dir() or any(self.root.iterdir())):
            raise InvalidInputError(f"--record folder {str(self.root)!r} exists and is not empty")
        self.config = config or RecordConfig()
        self._writer = None
        self._cameras: tuple[str, ...] | None = None
        atexit.register(self.close)

    @property
    def num_episodes(self) -> int:
        return 0 if self._writer is None else self._writer.num_episodes

    def add(
        self,
        recording: RecordedEpisode | None,
        task: str,
        success: bool,
        reason: str,
        seed: int | None,
        scene: str,
    ) -> int | None:
        """Write one episode; returns its episode_index (None when there is nothing recorded)."""
        from sim.lerobot_dataset import LeRobotDatasetWriter

        if recording is None or recording.num_frames == 0:
            log.warning("episode %r (seed %s) has no recording; not written", task, seed)
            return None
        cameras = tuple(recording.images)
        if self._writer is None:
            self._cameras = cameras
            self._writer = LeRobotDatasetWriter(
                self.root,
                recording.fps,
                lerobot_features(list(cameras), self.config),
                robot_type=f"{recording.robot}_{recording.gripper}",
            )
        elif cameras != self._cameras:
            raise InvalidInputError(
                f"episode cameras {cameras} differ from the dataset's {self._cameras}; record one scene kind "
                "per dataset"
            )
        extra = {"success": bool(success), "reason": str(reason), "seed": -1 if seed is None else int(seed)}
        extra["scene"] = str(scene)
        return self._writer.add_episode(task, recording.lerobot_frames(), extra)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
        atexit.unregister(self.close)
