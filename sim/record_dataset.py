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
from sim.recording import RecordConfig, RecordedEpisode

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
        self._features: dict | None = None
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
        features = recording.lerobot_features()
        if self._writer is None:
            self._features = features
            self._writer = LeRobotDatasetWriter(
                self.root, recording.fps, features, robot_type=f"{recording.robot}_{recording.gripper}"
            )
        elif features != self._features or recording.fps != self._writer.fps:
            raise InvalidInputError(
                f"episode features {sorted(features)} at {recording.fps} fps differ from the dataset's "
                f"{sorted(self._features)} at {self._writer.fps} fps; record one scene kind per dataset"
            )
        extra = {"success": bool(success), "reason": str(reason), "seed": -1 if seed is None else int(seed)}
        extra["scene"] = str(scene)
        return self._writer.add_episode(task, recording.lerobot_frames(), extra)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
        atexit.unregister(self.close)


#: Replay tolerances [rad] (docs/recording.md): per frame, and the 95th percentile of an episode's frames.
#: Between ticks the replay interpolates 20 Hz set-points where the arm ran its 500 Hz profile (~1e-4 rad),
#: and a gripper command that jumped somewhere inside a period (a squeeze's final push) is applied over the
#: whole period: a grasp's contact then deflects the wrist for a few frames (3.5e-3 rad at most over 20
#: tabletop episodes, gone within 3 frames). 1e-2 rad is 0.6 degree (~8 mm at a UR5e's TCP): a replay that
#: lost a grasp or hit something is off by more and for longer; 1e-3 rad bounds the rest of the frames.
REPLAY_TOL_RAD = 1e-2
REPLAY_TOL_P95_RAD = 1e-3


def check_dataset(root: str | Path, replay: bool = True) -> dict:
    """Read a `--record` dataset back as lerobot does and check it: the frames with Hugging Face `datasets`
    (counts, timestamps k / fps, indices), the episodes meta (frame and video ranges), every video with PyAV
    (one frame per dataset frame, each episode's frames at from_timestamp + k / fps within lerobot's 1e-4 s);
    with `replay`, each episode's actions replayed in its scene and seed (`sim.recording.replay_in_scene`)
    against its recorded joints. Returns a report; raises InvalidInputError on the first mismatch."""
    import json

    import numpy as np

    from prompose_grasp._optional import require

    datasets = require("datasets", extra="test")
    av = require("av", extra="record")
    root = Path(root)
    info = json.loads((root / "meta" / "info.json").read_text())
    fps = int(info["fps"])

    def fail(what: str) -> None:
        raise InvalidInputError(f"{root}: {what}")

    frames = datasets.load_dataset("parquet", data_files=str(root / "data/*/*.parquet"), split="train")
    eps = datasets.load_dataset(
        "parquet", data_files=str(root / "meta/episodes/*/*.parquet"), split="train"
    ).to_dict()
    if len(frames) != info["total_frames"] or len(eps["length"]) != info["total_episodes"]:
        fail(f"{len(frames)} frames / {len(eps['length'])} episodes, info.json says {info['total_frames']} / "
             f"{info['total_episodes']}")  # fmt: skip
    ep_col = np.asarray(frames["episode_index"])
    ts = np.asarray(frames["timestamp"], dtype=np.float64)
    video_keys = [k for k, f in info["features"].items() if f["dtype"] == "video"]
    pts: dict[tuple[str, int, int], np.ndarray] = {}  # (key, chunk, file) -> frame times [s]
    for key in video_keys:
        for e in range(len(eps["length"])):
            c, f = eps[f"videos/{key}/chunk_index"][e], eps[f"videos/{key}/file_index"][e]
            if (key, c, f) not in pts:
                path = root / info["video_path"].format(video_key=key, chunk_index=c, file_index=f)
                with av.open(str(path)) as container:
                    pts[key, c, f] = np.array([float(x.pts * x.time_base) for x in container.decode(video=0)])
        n_video = sum(len(t) for (k, _, _), t in pts.items() if k == key)
        if n_video != len(frames):
            fail(f"{key}: {n_video} video frames for {len(frames)} dataset frames")
    report: dict = {"episodes": len(eps["length"]), "frames": len(frames), "fps": fps}
    report.update(replay_max_rad=[], replay_p95_rad=[])
    action = np.asarray(frames["action"], dtype=np.float64)
    state = np.asarray(frames["observation.state"], dtype=np.float64)
    for e, n in enumerate(eps["length"]):
        lo, hi = eps["dataset_from_index"][e], eps["dataset_to_index"][e]
        if hi - lo != n or not np.all(ep_col[lo:hi] == e):
            fail(f"episode {e}: rows {lo}:{hi} are not its {n} frames")
        if np.max(np.abs(ts[lo:hi] - np.arange(n) / fps)) > 1e-4:
            fail(f"episode {e}: timestamps are not k / {fps}")
        for key in video_keys:
            t0 = eps[f"videos/{key}/from_timestamp"][e]
            if abs(eps[f"videos/{key}/to_timestamp"][e] - t0 - n / fps) > 1e-4:
                fail(f"episode {e}: {key} range is not {n} frames long")
            times = pts[key, eps[f"videos/{key}/chunk_index"][e], eps[f"videos/{key}/file_index"][e]]
            k0 = round(t0 * fps)
            if len(times) < k0 + n or np.max(np.abs(times[k0 : k0 + n] - (t0 + np.arange(n) / fps))) > 1e-4:
                fail(f"episode {e}: {key} frames are not at from_timestamp + k / {fps}")
        if replay:
            from sim.recording import replay_in_scene

            q = replay_in_scene(eps["scene"][e], eps["seed"][e], action[lo:hi], fps)
            err = np.max(np.abs(q - state[lo:hi, :6]), axis=1)  # (n,) per frame
            worst, p95 = float(err.max()), float(np.quantile(err, 0.95))
            report["replay_max_rad"].append(worst)
            report["replay_p95_rad"].append(p95)
            if worst > REPLAY_TOL_RAD or p95 > REPLAY_TOL_P95_RAD:
                fail(f"episode {e}: replayed joints off the recorded ones by {worst:.2e} rad (95 % of frames "
                     f"within {p95:.2e}; tolerances {REPLAY_TOL_RAD}, {REPLAY_TOL_P95_RAD})")  # fmt: skip
    report["successes"] = int(sum(bool(s) for s in eps.get("success", [])))
    return report


if __name__ == "__main__":
    import argparse
    import json as _json

    p = argparse.ArgumentParser(prog="python -m sim.record_dataset", description=check_dataset.__doc__)
    p.add_argument("root", help="a dataset written with --record")
    p.add_argument("--no-replay", action="store_true", help="skip replaying the actions")
    a = p.parse_args()
    print(_json.dumps(check_dataset(a.root, replay=not a.no_replay), indent=2))
