"""The LeRobot v3.0 dataset writer (`sim.lerobot_dataset`) read back as lerobot reads it: the parquet files
with Hugging Face `datasets`, the videos with PyAV, the meta files against lerobot's v3.0 layout."""

from __future__ import annotations

import json

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError

pytest.importorskip("pyarrow")
pytest.importorskip("pandas")
av = pytest.importorskip("av")
datasets = pytest.importorskip("datasets")

from sim.lerobot_dataset import CODEBASE_VERSION, LeRobotDatasetWriter  # noqa: E402

FPS = 20
H, W = 32, 48
FEATURES = {
    "observation.state": {"dtype": "float32", "shape": [3], "names": ["a", "b", "c"]},
    "action": {"dtype": "float32", "shape": [2], "names": ["x", "y"]},
    "observation.images.front": {
        "dtype": "video",
        "shape": [H, W, 3],
        "names": ["height", "width", "channels"],
    },
}
#: meta/info.json's keys as lerobot's `create_empty_dataset_info` writes them (v3.0)
INFO_KEYS = {
    "codebase_version", "robot_type", "total_episodes", "total_frames", "total_tasks", "chunks_size",
    "data_files_size_in_mb", "video_files_size_in_mb", "fps", "splits", "data_path", "video_path", "features",
}  # fmt: skip
#: the per-episode columns lerobot's loader reads from meta/episodes (`LeRobotDatasetMetadata`)
EPISODE_KEYS = {
    "episode_index", "tasks", "length", "dataset_from_index", "dataset_to_index", "data/chunk_index",
    "data/file_index", "meta/episodes/chunk_index", "meta/episodes/file_index",
    "videos/observation.images.front/chunk_index", "videos/observation.images.front/file_index",
    "videos/observation.images.front/from_timestamp", "videos/observation.images.front/to_timestamp",
}  # fmt: skip
LENGTHS = (23, 31, 17)
TASKS = ("put the red mug in the bin", "pick up the green bottle", "put the red mug in the bin")


def _grey(index: int) -> int:
    """The grey level of the frame with dataset index `index`: distinct for neighbouring frames, so a frame
    read at the wrong time is seen (7 levels apart; the codec's error on a flat frame is ~1 level)."""
    return (7 * index) % 224 + 16


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("lerobot") / "ds"
    rng = np.random.default_rng(0)
    written = []
    index = 0
    with LeRobotDatasetWriter(root, FPS, FEATURES, robot_type="ur5e_parallel_jaw") as writer:
        for e, (n, task) in enumerate(zip(LENGTHS, TASKS)):
            frames = {
                "observation.state": rng.normal(size=(n, 3)),
                "action": rng.normal(size=(n, 2)),
                "observation.images.front": np.stack(
                    [np.full((H, W, 3), _grey(index + k), dtype=np.uint8) for k in range(n)]
                ),
            }
            writer.add_episode(task, frames, extra={"success": e != 1, "reason": f"r{e}", "seed": 10 + e})
            written.append(frames)
            index += n
    return root, written


def test_info_json_is_lerobot_v3_layout(dataset):
    root, _ = dataset
    info = json.loads((root / "meta" / "info.json").read_text())
    assert set(info) == INFO_KEYS
    assert info["codebase_version"] == CODEBASE_VERSION == "v3.0"
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    assert (info["fps"], info["total_episodes"], info["total_frames"], info["total_tasks"]) == (
        FPS, 3, sum(LENGTHS), 2
    )  # fmt: skip
    assert info["splits"] == {"train": "0:3"}
    assert (info["chunks_size"], info["data_files_size_in_mb"], info["video_files_size_in_mb"]) == (
        1000,
        100,
        200,
    )
    feats = info["features"]
    assert set(feats) == set(FEATURES) | {"timestamp", "frame_index", "episode_index", "index", "task_index"}
    assert feats["observation.state"] == FEATURES["observation.state"]
    assert feats["timestamp"] == {"dtype": "float32", "shape": [1], "names": None}
    video = feats["observation.images.front"]
    assert video["dtype"] == "video" and video["shape"] == [H, W, 3]
    assert video["info"]["video.codec"] in ("av1", "h264")
    assert (video["info"]["video.height"], video["info"]["video.width"], video["info"]["video.fps"]) == (
        H,
        W,
        FPS,
    )


def test_frames_read_back_with_datasets(dataset):
    root, written = dataset
    ds = datasets.load_dataset("parquet", data_files=str(root / "data/*/*.parquet"), split="train")
    assert len(ds) == sum(LENGTHS)
    assert ds.features["observation.state"] == datasets.List(datasets.Value("float32"), length=3)
    assert ds.features["index"] == datasets.Value("int64")
    np.testing.assert_array_equal(ds["index"], np.arange(sum(LENGTHS)))
    ep = np.asarray(ds["episode_index"])
    for e, n in enumerate(LENGTHS):
        rows = ds.select(np.flatnonzero(ep == e).tolist())
        np.testing.assert_array_equal(rows["frame_index"], np.arange(n))
        # lerobot checks timestamps against k / fps within tolerance_s = 1e-4 s; float32 of k / 20: 1e-6
        np.testing.assert_allclose(rows["timestamp"], np.arange(n) / FPS, atol=1e-6)
        np.testing.assert_array_equal(rows["task_index"], [0 if TASKS[e] == TASKS[0] else 1] * n)
        # float32 storage of float64 input
        np.testing.assert_allclose(rows["action"], written[e]["action"], rtol=1e-6)


def test_episode_meta_tasks_and_stats(dataset):
    root, written = dataset
    eps = datasets.load_dataset(
        "parquet", data_files=str(root / "meta/episodes/*/*.parquet"), split="train"
    ).to_dict()
    assert EPISODE_KEYS <= set(eps)
    assert eps["length"] == list(LENGTHS)
    assert eps["tasks"] == [[t] for t in TASKS]
    starts = np.concatenate([[0], np.cumsum(LENGTHS)[:-1]])
    assert eps["dataset_from_index"] == starts.tolist()
    assert eps["dataset_to_index"] == (starts + LENGTHS).tolist()
    np.testing.assert_allclose(eps["videos/observation.images.front/from_timestamp"], starts / FPS)
    np.testing.assert_allclose(eps["videos/observation.images.front/to_timestamp"], (starts + LENGTHS) / FPS)
    assert (eps["success"], eps["reason"], eps["seed"]) == (
        [True, False, True],
        ["r0", "r1", "r2"],
        [10, 11, 12],
    )
    # per-episode stats, as lerobot's compute_episode_stats: per dimension (vectors), per channel in [0, 1]
    # (of the stored float32 values: 1e-6)
    np.testing.assert_allclose(eps["stats/action/mean"][1], written[1]["action"].mean(axis=0), rtol=1e-6)
    assert np.shape(eps["stats/observation.images.front/mean"][0]) == (3, 1, 1)
    import pandas as pd

    tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
    assert tasks.loc[TASKS[0], "task_index"] == 0 and tasks.loc[TASKS[1], "task_index"] == 1
    stats = json.loads((root / "meta" / "stats.json").read_text())
    assert set(stats) == set(json.loads((root / "meta" / "info.json").read_text())["features"])
    assert set(stats["action"]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
    every = np.concatenate([w["action"] for w in written])
    assert stats["action"]["count"] == [sum(LENGTHS)]
    # the pooled mean / std of the episodes equal those of all frames (float32 storage: 1e-6)
    np.testing.assert_allclose(stats["action"]["mean"], every.mean(axis=0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats["action"]["std"], every.std(axis=0), rtol=1e-5)


def test_video_frames_sit_at_the_episode_timestamps(dataset):
    root, _ = dataset
    path = root / "videos/observation.images.front/chunk-000/file-000.mp4"
    with av.open(str(path)) as container:
        frames = [
            (float(f.pts * f.time_base), f.to_ndarray(format="rgb24")) for f in container.decode(video=0)
        ]
    assert len(frames) == sum(LENGTHS)
    starts = np.concatenate([[0], np.cumsum(LENGTHS)[:-1]])
    for e, n in enumerate(LENGTHS):
        for k in (0, n // 2, n - 1):  # first, middle, last frame of each episode
            t, img = frames[starts[e] + k]
            # the frame lerobot decodes for (episode e, timestamp k / fps): within its 1e-4 s tolerance
            assert abs(t - (starts[e] + k) / FPS) < 1e-4
            # and it shows that frame: its grey level within 3 of the written one (lossy codec on a flat
            # frame: ~1 level; neighbouring frames are 7 apart)
            assert abs(float(img.mean()) - _grey(starts[e] + k)) < 3.0


def test_bad_input(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(InvalidInputError, match="not empty"):
        LeRobotDatasetWriter(tmp_path / "full", FPS, FEATURES)
    with pytest.raises(InvalidInputError, match="fps"):
        LeRobotDatasetWriter(tmp_path / "a", 0, FEATURES)
    with pytest.raises(InvalidInputError, match="lerobot's own"):
        LeRobotDatasetWriter(tmp_path / "b", FPS, {"index": {"dtype": "int64", "shape": [1]}})
    with LeRobotDatasetWriter(tmp_path / "c", FPS, FEATURES) as w:
        with pytest.raises(InvalidInputError, match="missing"):
            w.add_episode("task", {"action": np.zeros((2, 2))})
        frames = {
            "observation.state": np.zeros((2, 3)),
            "action": np.zeros((3, 2)),
            "observation.images.front": np.zeros((2, H, W, 3), np.uint8),
        }
        with pytest.raises(InvalidInputError, match="same number"):
            w.add_episode("task", frames)
        with pytest.raises(InvalidInputError, match="task"):
            w.add_episode("", frames)


def test_check_dataset_accepts_it_and_catches_a_bad_range(dataset, tmp_path):
    import shutil

    import pyarrow.parquet as pq

    from sim.record_dataset import check_dataset

    root, _ = dataset
    report = check_dataset(root, replay=False)
    assert (report["episodes"], report["frames"], report["successes"]) == (3, sum(LENGTHS), 2)
    bad = tmp_path / "bad"
    shutil.copytree(root, bad)
    path = bad / "meta/episodes/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    col = table.column_names.index("videos/observation.images.front/from_timestamp")
    shifted = [t + 1.0 / FPS for t in table.column(col).to_pylist()]  # starts one frame late
    pq.write_table(table.set_column(col, table.schema.field(col), [shifted]), path)
    with pytest.raises(InvalidInputError, match="range is not 23 frames long"):
        check_dataset(bad, replay=False)
