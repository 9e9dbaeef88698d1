"""Episodes written as a LeRobot dataset, codebase version v3.0 as lerobot 0.4.2 writes it, without lerobot.

lerobot itself is no dependency (its releases pin torch below the version here and pull torchvision, diffusers
and wandb); this module writes its documented v3.0 layout with the libraries lerobot uses underneath: pyarrow
parquet files (with the Hugging Face `datasets` feature schema in their metadata, as `datasets` writes it),
PyAV mp4 videos and lerobot's meta JSON / parquet files. Layout, defaults and stats follow lerobot 0.4.2's
`lerobot/datasets/{utils,lerobot_dataset,video_utils,compute_stats}.py` (`CODEBASE_VERSION = "v3.0"`)::

    ROOT/meta/info.json                            codebase_version, fps, features, path templates, totals
    ROOT/meta/stats.json                           min / max / mean / std / count / q01..q99 per feature
    ROOT/meta/tasks.parquet                        task text (the index) -> task_index
    ROOT/meta/episodes/chunk-000/file-000.parquet  one row per episode: length, tasks, frame and video
                                                   ranges, per-episode stats, success, reason, seed
    ROOT/data/chunk-{c:03d}/file-{f:03d}.parquet   one row per frame, many episodes per file
    ROOT/videos/{video_key}/chunk-{c:03d}/file-{f:03d}.mp4   many episodes per file, one after the other

Files roll over at lerobot's default sizes (data 100 MB, video 200 MB, 1000 files per chunk). Frame k of an
episode has `timestamp` k / fps; in its video file it is the frame at `from_timestamp + timestamp`.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError

__all__ = [
    "CODEBASE_VERSION",
    "DEFAULT_FEATURES",
    "LEROBOT_VERSION",
    "LeRobotDatasetWriter",
    "aggregate_stats",
    "episode_stats",
]

log = logging.getLogger(__name__)

#: The dataset layout version written (lerobot's `CODEBASE_VERSION`).
CODEBASE_VERSION = "v3.0"
#: The lerobot release whose layout and defaults this follows (checked against its wheel); v3.0 datasets came
#: with lerobot 0.4.0.
LEROBOT_VERSION = "0.4.2"
DEFAULT_CHUNK_SIZE = 1000  # files per chunk folder
DEFAULT_DATA_FILE_SIZE_IN_MB = 100
DEFAULT_VIDEO_FILE_SIZE_IN_MB = 200
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
TASKS_PATH = "meta/tasks.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
#: The columns lerobot adds to every dataset.
DEFAULT_FEATURES: dict[str, dict[str, Any]] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
#: lerobot's quantiles of every feature (`compute_stats.DEFAULT_QUANTILES`), keys q01 .. q99.
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
#: Video encoding: lerobot's defaults (`encode_video_frames`: SVT-AV1, yuv420p, a key frame every 2 frames so
#: any frame decodes fast, crf 30); preset 8, as SVT-AV1 warns that its presets 10 and up are for automated
#: pipelines and may show artefacts. H.264 where this PyAV has no SVT-AV1 encoder.
VIDEO_CODECS = ("libsvtav1", "libx264")
_VIDEO_OPTIONS = {"libsvtav1": {"g": "2", "crf": "30", "preset": "8"}, "libx264": {"g": "2", "crf": "23"}}


def _sample_indices(n: int) -> np.ndarray:
    """lerobot's `sample_indices`: the frames of an episode its image stats look at (100 up to ~500
    frames, n^0.75 beyond, at most 10,000), evenly spread."""
    k = max(min(100, n), min(int(n**0.75), 10_000))
    return np.round(np.linspace(0, n - 1, k)).astype(int)


def _stats(x: np.ndarray, axis: int | tuple[int, ...], keepdims: bool) -> dict[str, np.ndarray]:
    out = {
        "min": np.min(x, axis=axis, keepdims=keepdims),
        "max": np.max(x, axis=axis, keepdims=keepdims),
        "mean": np.mean(x, axis=axis, keepdims=keepdims),
        "std": np.std(x, axis=axis, keepdims=keepdims),
        "count": np.array([len(x)]),
    }
    for q in QUANTILES:
        out[f"q{round(100 * q):02d}"] = np.quantile(x, q, axis=axis, keepdims=keepdims)
    return out


def episode_stats(columns: Mapping[str, np.ndarray], features: Mapping[str, dict]) -> dict[str, dict]:
    """Per-feature stats of one episode as lerobot's `compute_episode_stats` makes them: vectors per
    dimension over the frames; images per channel over sampled frames, in [0, 1], shaped (3, 1, 1)."""
    out: dict[str, dict] = {}
    for key, data in columns.items():
        ft = features[key]
        if ft["dtype"] in ("video", "image"):
            imgs = np.asarray(data)[_sample_indices(len(data))]  # (k, H, W, 3) uint8
            chw = np.moveaxis(imgs, -1, 1).astype(np.float64) / 255.0  # (k, 3, H, W)
            s = _stats(chw, axis=(0, 2, 3), keepdims=True)
            out[key] = {k: v if k == "count" else np.squeeze(v, axis=0) for k, v in s.items()}
        else:
            arr = np.asarray(data, dtype=np.float64)
            out[key] = _stats(arr, axis=0, keepdims=arr.ndim == 1)
    return out


def aggregate_stats(stats_list: list[dict[str, dict]]) -> dict[str, dict[str, np.ndarray]]:
    """lerobot's `aggregate_stats`: min of mins, max of maxes, count-weighted mean, the pooled std (parallel
    variance), quantiles as the count-weighted mean of the episodes' quantiles."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for key in {k for s in stats_list for k in s}:
        items = [s[key] for s in stats_list if key in s]
        counts = np.stack([s["count"] for s in items]).astype(np.float64)
        total = counts.sum(axis=0)
        means = np.stack([s["mean"] for s in items])
        w = counts
        while w.ndim < means.ndim:
            w = w[..., None]
        mean = (means * w).sum(axis=0) / total
        var = ((np.stack([s["std"] for s in items]) ** 2 + (means - mean) ** 2) * w).sum(axis=0) / total
        agg = {
            "min": np.min(np.stack([s["min"] for s in items]), axis=0),
            "max": np.max(np.stack([s["max"] for s in items]), axis=0),
            "mean": mean,
            "std": np.sqrt(var),
            "count": total.astype(np.int64),
        }
        for q in [k for k in items[0] if k.startswith("q")]:
            agg[q] = (np.stack([s[q] for s in items]) * w).sum(axis=0) / total
        out[key] = agg
    return out


def _jsonable(stats: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, Any]]:
    return {k: {s: np.asarray(v).tolist() for s, v in d.items()} for k, d in stats.items()}


class _VideoFile:
    """One mp4 being written: frames appended across episodes at `fps`, frame i at i / fps seconds."""

    def __init__(self, path: Path, fps: int, width: int, height: int, codec: str):
        import av

        # SVT-AV1 prints its configuration and warnings to stderr at every encoder start unless told to keep
        # to errors (it reads this once, when its first encoder starts)
        os.environ.setdefault("SVT_LOG", "1")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.container = av.open(str(path), mode="w")
        self.stream = self.container.add_stream(codec, rate=fps, options=dict(_VIDEO_OPTIONS[codec]))
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = "yuv420p"
        self.stream.time_base = Fraction(1, fps)
        self.frames = 0
        self._av = av

    def add(self, images: np.ndarray) -> None:
        """Append (n, H, W, 3) uint8 RGB frames."""
        for img in images:
            frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            frame.pts = self.frames
            self.frames += 1
            self.container.mux(self.stream.encode(frame))

    def size_mb(self) -> float:
        return self.path.stat().st_size / 1024**2 if self.path.exists() else 0.0

    def close(self) -> None:
        self.container.mux(self.stream.encode(None))  # flush the encoder's delayed frames
        self.container.close()


def _hf_feature(ft: dict[str, Any]) -> dict[str, Any]:
    """The `datasets` feature (as `datasets.Features.to_dict` writes it) lerobot's
    `get_hf_features_from_features` makes of an info.json feature."""
    value = {"dtype": ft["dtype"], "_type": "Value"}
    if list(ft["shape"]) == [1]:
        return value
    if len(ft["shape"]) == 1:
        return {"feature": value, "length": int(ft["shape"][0]), "_type": "List"}
    raise InvalidInputError(f"only scalar and 1-d features are written here, got shape {ft['shape']}")


class LeRobotDatasetWriter:
    """Writes episodes into a new LeRobot v3.0 dataset at `root` (see the module docstring).

    Args:
        root: the dataset folder; must not exist or be empty.
        fps: frames per second of every episode (the control rate).
        features: {key: {"dtype": "float32" | "video", "shape": [...], "names": [...]}} without lerobot's
            default columns (added here); video features are (H, W, 3) uint8 frames.
        robot_type: info.json's robot_type.
        codec: video codec; default the first of `VIDEO_CODECS` this PyAV can encode.

    Use as a context manager, or call `close()`: the videos and the meta files are complete only then.
    `add_episode` writes one episode; extra per-episode columns (success, reason, seed) go into the episodes
    meta parquet next to lerobot's own.
    """

    def __init__(
        self,
        root: str | Path,
        fps: int,
        features: Mapping[str, dict[str, Any]],
        robot_type: str | None = None,
        codec: str | None = None,
    ):
        require("pyarrow", extra="record")
        require("av", extra="record")
        require("pandas", extra="record")
        import av

        self.root = Path(root)
        if self.root.exists() and (not self.root.is_dir() or any(self.root.iterdir())):
            raise InvalidInputError(f"dataset folder {str(self.root)!r} exists and is not empty")
        if isinstance(fps, bool) or not isinstance(fps, int) or fps <= 0:
            raise InvalidInputError(f"fps must be a positive integer, got {fps!r}")
        bad = [k for k in features if "/" in k or k in DEFAULT_FEATURES]
        if bad:
            raise InvalidInputError(f"feature names may not contain '/' nor be lerobot's own columns: {bad}")
        for key, ft in features.items():
            if ft["dtype"] == "video" and (len(ft["shape"]) != 3 or ft["shape"][2] != 3):
                raise InvalidInputError(f"video feature {key!r} must be (H, W, 3), got {ft['shape']}")
            if ft["dtype"] not in ("video", "float32", "int64", "bool"):
                raise InvalidInputError(f"feature {key!r}: dtype {ft['dtype']!r} is not written here")
        if codec is None:
            codec = next((c for c in VIDEO_CODECS if c in av.codecs_available), None)
            if codec is None:
                raise InvalidInputError(f"this PyAV can encode none of {VIDEO_CODECS}")
        if codec not in _VIDEO_OPTIONS:
            raise InvalidInputError(f"unknown video codec {codec!r}; known: {', '.join(_VIDEO_OPTIONS)}")
        self.fps = fps
        self.codec = codec
        self.features: dict[str, dict[str, Any]] = {
            k: {"dtype": v["dtype"], "shape": list(v["shape"]), "names": v.get("names")}
            for k, v in features.items()
        }
        self.features.update({k: dict(v) for k, v in DEFAULT_FEATURES.items()})
        self.video_keys = [k for k, v in self.features.items() if v["dtype"] == "video"]
        self.data_keys = [k for k, v in self.features.items() if v["dtype"] != "video"]
        self.robot_type = robot_type
        self.tasks: dict[str, int] = {}
        self.episodes: list[dict[str, Any]] = []
        self.stats: list[dict[str, dict]] = []
        self.total_frames = 0
        self._data_file = (0, 0)  # (chunk, file)
        self._data_writer = None
        self._data_mb = 0.0
        self._videos: dict[str, _VideoFile] = {}
        self._video_file = dict.fromkeys(self.video_keys, (0, 0))
        self._video_info: dict[str, dict[str, Any]] = {}
        self._closed = False
        self.root.mkdir(parents=True, exist_ok=True)

    # ------------------------------------------------------------------------------------------------
    def __enter__(self) -> LeRobotDatasetWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def num_episodes(self) -> int:
        return len(self.episodes)

    def _next_file(self, chunk_file: tuple[int, int]) -> tuple[int, int]:
        chunk, file = chunk_file
        return (chunk + 1, 0) if file == DEFAULT_CHUNK_SIZE - 1 else (chunk, file + 1)

    def _data_schema(self):
        import pyarrow as pa

        types = {"float32": pa.float32(), "int64": pa.int64(), "bool": pa.bool_()}
        fields = []
        for k in self.data_keys:
            ft = self.features[k]
            t = types[ft["dtype"]]
            fields.append(pa.field(k, t if ft["shape"] == [1] else pa.list_(t, int(ft["shape"][0]))))
        hf = {"info": {"features": {k: _hf_feature(self.features[k]) for k in self.data_keys}}}
        return pa.schema(fields, metadata={"huggingface": json.dumps(hf)})

    def add_episode(
        self, task: str, frames: Mapping[str, np.ndarray], extra: Mapping[str, Any] | None = None
    ) -> int:
        """Write one episode and return its episode_index.

        Args:
            task: the episode's language instruction (lerobot's task).
            frames: {feature key: (n, ...) array} for every feature given at construction (video features:
                (n, H, W, 3) uint8); n >= 1 frames at `fps`.
            extra: scalar per-episode columns for the episodes meta file (success, reason, seed ...).
        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        if self._closed:
            raise InvalidInputError("the dataset writer is closed")
        if not isinstance(task, str) or not task.strip():
            raise InvalidInputError(f"task must be a non-empty string, got {task!r}")
        own = [k for k in self.features if k not in DEFAULT_FEATURES]
        missing, unknown = sorted(set(own) - set(frames)), sorted(set(frames) - set(own))
        if missing or unknown:
            raise InvalidInputError(f"episode features: missing {missing}, unknown {unknown}; expected {own}")
        lengths = {k: len(frames[k]) for k in own}
        n = next(iter(lengths.values()))
        if n < 1 or any(v != n for v in lengths.values()):
            raise InvalidInputError(f"every feature needs the same number (>= 1) of frames, got {lengths}")
        for k in own:
            want = tuple(self.features[k]["shape"])
            got = tuple(np.shape(frames[k])[1:]) or (1,)
            if got != want:
                raise InvalidInputError(f"feature {k!r}: frames of shape {got}, expected {want}")
        ep = len(self.episodes)
        if task not in self.tasks:
            self.tasks[task] = len(self.tasks)
        columns: dict[str, np.ndarray] = {
            k: np.asarray(frames[k], dtype=np.float32 if self.features[k]["dtype"] == "float32" else None)
            for k in own
        }
        columns.update(
            timestamp=(np.arange(n) / self.fps).astype(np.float32),
            frame_index=np.arange(n, dtype=np.int64),
            episode_index=np.full(n, ep, dtype=np.int64),
            index=np.arange(self.total_frames, self.total_frames + n, dtype=np.int64),
            task_index=np.full(n, self.tasks[task], dtype=np.int64),
        )
        meta: dict[str, Any] = {"episode_index": ep, "tasks": [task], "length": n}
        # ---- frames (parquet): a new file once this one would pass the size limit
        schema = self._data_schema()
        arrays = []
        for k in self.data_keys:
            col = columns[k]
            f = schema.field(k)
            if col.ndim == 1:
                arrays.append(pa.array(col, type=f.type))
            else:
                flat = pa.array(col.reshape(-1), type=f.type.value_type)
                arrays.append(pa.FixedSizeListArray.from_arrays(flat, col.shape[1]))
        table = pa.Table.from_arrays(arrays, schema=schema)
        mb = table.nbytes / 1024**2
        if self._data_writer is not None and self._data_mb + mb >= DEFAULT_DATA_FILE_SIZE_IN_MB:
            self._data_writer.close()
            self._data_writer, self._data_mb = None, 0.0
            self._data_file = self._next_file(self._data_file)
        if self._data_writer is None:
            c, f_ = self._data_file
            path = self.root / DATA_PATH.format(chunk_index=c, file_index=f_)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._data_writer = pq.ParquetWriter(path, schema, compression="snappy")
        self._data_writer.write_table(table)
        self._data_mb += mb
        meta["data/chunk_index"], meta["data/file_index"] = self._data_file
        meta["dataset_from_index"] = self.total_frames
        meta["dataset_to_index"] = self.total_frames + n
        # ---- videos: appended to the key's current file; a new file past the size limit
        for k in self.video_keys:
            video = self._videos.get(k)
            if video is not None and video.size_mb() >= DEFAULT_VIDEO_FILE_SIZE_IN_MB:
                video.close()
                video = None
                self._video_file[k] = self._next_file(self._video_file[k])
            if video is None:
                c, f_ = self._video_file[k]
                h, w, _ = self.features[k]["shape"]
                path = self.root / VIDEO_PATH.format(video_key=k, chunk_index=c, file_index=f_)
                video = self._videos[k] = _VideoFile(path, self.fps, w, h, self.codec)
            start = video.frames
            video.add(np.asarray(frames[k], dtype=np.uint8))
            meta[f"videos/{k}/chunk_index"], meta[f"videos/{k}/file_index"] = self._video_file[k]
            meta[f"videos/{k}/from_timestamp"] = start / self.fps
            meta[f"videos/{k}/to_timestamp"] = (start + n) / self.fps
        # ---- stats
        stats = episode_stats(columns, self.features)
        self.stats.append(stats)
        for feat, d in stats.items():
            for s, v in d.items():
                meta[f"stats/{feat}/{s}"] = np.asarray(v).tolist()
        meta["meta/episodes/chunk_index"], meta["meta/episodes/file_index"] = 0, 0
        for key, value in (extra or {}).items():
            if key in meta:
                raise InvalidInputError(f"extra column {key!r} is one of lerobot's")
            meta[key] = value
        self.episodes.append(meta)
        self.total_frames += n
        self._write_meta()
        return ep

    # ------------------------------------------------------------------------------------------------
    def info(self) -> dict[str, Any]:
        """meta/info.json as lerobot's `create_empty_dataset_info` lays it out, with the totals so far."""
        features = json.loads(json.dumps(self.features))
        for k in self.video_keys:
            h, w, c = self.features[k]["shape"]
            features[k]["names"] = ["height", "width", "channels"]
            features[k]["info"] = self._video_info.get(k) or {
                "video.height": h,
                "video.width": w,
                "video.codec": {"libsvtav1": "av1", "libx264": "h264"}[self.codec],
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": False,
                "video.fps": self.fps,
                "video.channels": c,
                "has_audio": False,
            }
        n = len(self.episodes)
        return {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.robot_type,
            "total_episodes": n,
            "total_frames": self.total_frames,
            "total_tasks": len(self.tasks),
            "chunks_size": DEFAULT_CHUNK_SIZE,
            "data_files_size_in_mb": DEFAULT_DATA_FILE_SIZE_IN_MB,
            "video_files_size_in_mb": DEFAULT_VIDEO_FILE_SIZE_IN_MB,
            "fps": self.fps,
            "splits": {"train": f"0:{n}"} if n else {},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.video_keys else None,
            "features": features,
        }

    def _write_meta(self) -> None:
        """info.json, stats.json, tasks.parquet and the episodes parquet as they stand (rewritten after each
        episode, so a stopped run leaves readable meta for the frames written)."""
        import pandas as pd
        import pyarrow as pa
        import pyarrow.parquet as pq

        meta = self.root / "meta"
        meta.mkdir(parents=True, exist_ok=True)
        (self.root / INFO_PATH).write_text(json.dumps(self.info(), indent=4))
        (self.root / STATS_PATH).write_text(json.dumps(_jsonable(aggregate_stats(self.stats)), indent=4))
        tasks = pd.DataFrame({"task_index": list(self.tasks.values())}, index=list(self.tasks))
        tasks.to_parquet(self.root / TASKS_PATH)
        path = self.root / EPISODES_PATH.format(chunk_index=0, file_index=0)
        path.parent.mkdir(parents=True, exist_ok=True)
        keys = list(self.episodes[0])
        table = pa.Table.from_pydict({k: [e.get(k) for e in self.episodes] for k in keys})
        pq.write_table(table, path, compression="snappy")

    def close(self) -> None:
        """Finish the videos (their encoders' delayed frames, the mp4 index) and the data file; write the
        meta files with the videos' stream info as lerobot's `get_video_info` reads it."""
        if self._closed:
            return
        self._closed = True
        if self._data_writer is not None:
            self._data_writer.close()
        for k, video in self._videos.items():
            video.close()
            self._video_info[k] = video_info(video.path)
        if self.episodes:
            self._write_meta()


def video_info(path: str | Path) -> dict[str, Any]:
    """A video's stream info as lerobot's `video_utils.get_video_info` records it in info.json."""
    import av

    with av.open(str(path)) as container:
        s = container.streams.video[0]
        return {
            "video.height": s.height,
            "video.width": s.width,
            "video.codec": s.codec_context.codec.canonical_name,
            "video.pix_fmt": s.pix_fmt,
            "video.is_depth_map": False,
            "video.fps": int(s.base_rate),
            "video.channels": 3,
            "has_audio": len(container.streams.audio) > 0,
        }
