"""Training data for the network: the synthetic dataset (DESIGN.md "Synthetic dataset") -> object tracks ->
batches of windows, with the paper's augmentation (colour jitter, up to 20 % point dropout).

This module reads the dataset files itself (it sits below `prompose_grasp.eval` in the import layers). Ground
truth (poses, instance masks) is read here for training only; the masks play the grounding step (an oracle
mask, named so), the poses are the regression targets.

- `load_tracks(data_dir, split, config, ...)`: one `ObjectTrack` per (scene, object): per-frame object crop,
  farthest-point-sampled observed cloud and ground-truth pose, plus the prompt's frozen text token features
  and the text-retrieved canonical prior (`PriorLibrary.generate`), computed once.
- `make_windows(tracks, window, stride)` and `collate(tracks, windows, ...)`: `NetworkBatch` tensors.

Zero-shot protocol: `train` and `val` tracks never hold a category of the split's test categories, and `test`
tracks hold only those (distractors are dropped).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import Tensor

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project, farthest_point_sampling, robust_descriptor
from prompose_grasp.perception.dataset import GroundTruthObject, read_split, scene_frames
from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.losses import symmetry_codes
from prompose_grasp.perception.priors import PriorLibrary
from prompose_grasp.perception.priors.prior import SYMMETRIES
from prompose_grasp.perception.text import TextEncoder

__all__ = [
    "SPLITS",
    "AugmentConfig",
    "NetworkBatch",
    "ObjectTrack",
    "collate",
    "load_tracks",
    "make_windows",
    "object_crop",
    "observed_points",
]

log = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
#: Crops are padded by this fraction of the mask's bounding box on each side (context around the object).
_CROP_MARGIN = 0.1


@dataclass(frozen=True, eq=False)
class ObjectTrack:
    """One object over the frames of one scene, preprocessed for the network.

    Attributes:
        scene, instance_id, category, prompt, symmetry: identity of the object (symmetry in `SYMMETRIES`).
        crops: (F, S, S, 3) uint8 RGB object crops, S = config.crop_px.
        points: (F, N, 3) float32 observed points, camera frame [m], N = config.observed_points.
        frame_valid: (F,) bool, False where the object had too few depth points (its rows are copies).
        R_cam_obj: (F, 3, 3) float32 ground-truth rotation; t_cam_obj_m: (F, 3) float32 box centre [m];
            size_m: (F, 3) float32 box extents [m].
        text_tokens: (L, D) float32 frozen text token features of `prompt`.
        prior_points: (Np, 3) float32 canonical prior, unit box, Np = config.prior_points.
    """

    scene: str
    instance_id: int
    category: str
    prompt: str
    symmetry: str
    crops: np.ndarray
    points: np.ndarray
    frame_valid: np.ndarray
    R_cam_obj: np.ndarray
    t_cam_obj_m: np.ndarray
    size_m: np.ndarray
    text_tokens: np.ndarray
    prior_points: np.ndarray

    def __post_init__(self) -> None:
        F = self.crops.shape[0]
        shapes = {
            "points": (self.points, (F, None, 3)),
            "frame_valid": (self.frame_valid, (F,)),
            "R_cam_obj": (self.R_cam_obj, (F, 3, 3)),
            "t_cam_obj_m": (self.t_cam_obj_m, (F, 3)),
            "size_m": (self.size_m, (F, 3)),
            "prior_points": (self.prior_points, (None, 3)),
        }
        if self.crops.ndim != 4 or self.crops.shape[3] != 3 or F < 1:
            raise InvalidInputError(f"crops must be (F >= 1, S, S, 3), got {self.crops.shape}")
        for name, (arr, shape) in shapes.items():
            if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
                raise InvalidInputError(f"ObjectTrack.{name} must have shape {shape}, got {arr.shape}")
        if self.text_tokens.ndim != 2 or self.text_tokens.shape[0] < 1:
            raise InvalidInputError(f"text_tokens must be (L >= 1, D), got {self.text_tokens.shape}")
        if self.symmetry not in SYMMETRIES:
            raise UnknownNameError("symmetry", self.symmetry, SYMMETRIES)
        if not self.frame_valid.any():
            raise InvalidInputError(f"track {self.scene}/{self.instance_id} has no valid frame")

    @property
    def num_frames(self) -> int:
        return int(self.crops.shape[0])


@dataclass(frozen=True)
class AugmentConfig:
    """Online augmentation (paper section 4.1).

    Attributes:
        color_jitter: brightness, contrast and saturation factors are drawn from [1 - j, 1 + j] per frame.
        max_point_dropout: a fraction in [0, this] of the observed points is dropped per frame (and the cloud
            refilled by resampling the kept points, so its size stays fixed).
    """

    color_jitter: float = 0.2
    max_point_dropout: float = 0.2

    def __post_init__(self) -> None:
        if not 0.0 <= self.color_jitter < 1.0:
            raise InvalidInputError(f"color_jitter must be in [0, 1), got {self.color_jitter}")
        if not 0.0 <= self.max_point_dropout < 1.0:
            raise InvalidInputError(f"max_point_dropout must be in [0, 1), got {self.max_point_dropout}")


@dataclass(frozen=True, eq=False)
class NetworkBatch:
    """A batch of B windows of n frames (torch tensors; `inputs()` is what `ProMPoseNet` takes).

    crops (B, n, 3, S, S) float [0, 1]; points (B, n, N, 3) [m]; descriptors (B, n, 15) [m]; prior_points
    (B, Np, 3); text_tokens (B, L, D); text_valid (B, L) bool; frame_valid (B, n) bool;
    R_cam_obj (B, n, 3, 3); t_cam_obj_m (B, n, 3); size_m (B, n, 3); symmetry (B,) long codes.
    """

    crops: Tensor
    points: Tensor
    descriptors: Tensor
    prior_points: Tensor
    text_tokens: Tensor
    text_valid: Tensor
    frame_valid: Tensor
    R_cam_obj: Tensor
    t_cam_obj_m: Tensor
    size_m: Tensor
    symmetry: Tensor

    def to(self, device: str | torch.device) -> NetworkBatch:
        return NetworkBatch(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def rows(self, start: int, stop: int) -> NetworkBatch:
        """Windows [start, stop) of the batch (a data-parallel rank's shard)."""
        return NetworkBatch(**{f.name: getattr(self, f.name)[start:stop] for f in fields(self)})

    def inputs(self) -> dict[str, Tensor]:
        return {
            "crops": self.crops,
            "points": self.points,
            "descriptors": self.descriptors,
            "prior_points": self.prior_points,
            "text_tokens": self.text_tokens,
            "text_valid": self.text_valid,
            "frame_valid": self.frame_valid,
        }


def object_crop(rgb: np.ndarray, mask: np.ndarray, crop_px: int) -> np.ndarray:
    """The object-centric crop: (H, W, 3) uint8 RGB and (H, W) bool mask -> (crop_px, crop_px, 3) uint8.

    The square is centred on the mask's bounding box, its side the box's longer side plus a 10 % margin each
    way; parts outside the image are black.
    """
    v, u = np.nonzero(mask)
    if len(v) == 0:
        raise InvalidInputError("mask is empty; an object crop needs at least one pixel")
    cu, cv = 0.5 * (u.min() + u.max()), 0.5 * (v.min() + v.max())
    side = max(u.max() - u.min() + 1, v.max() - v.min() + 1) * (1.0 + 2.0 * _CROP_MARGIN)
    # An affine warp both crops and resizes, filling outside pixels with zeros.
    s = crop_px / side
    # Pixel edges: the square [c - side/2, c + side/2] maps onto [-0.5, crop_px - 0.5].
    A = np.array([[s, 0.0, crop_px / 2 - 0.5 - s * cu], [0.0, s, crop_px / 2 - 0.5 - s * cv]])
    return cv2.warpAffine(rgb, A, (crop_px, crop_px), flags=cv2.INTER_AREA, borderValue=(0, 0, 0))


def observed_points(
    depth_m: np.ndarray, intrinsics: CameraIntrinsics, mask: np.ndarray, n: int, min_points: int
) -> np.ndarray | None:
    """The masked depth back-projected and farthest-point-sampled to exactly `n` points: (n, 3) float32 [m].

    Fewer than `n` points are repeated cyclically; fewer than `min_points` gives None.
    """
    pts = back_project(depth_m, intrinsics, mask)
    if len(pts) < min_points:
        return None
    if len(pts) > n:
        pts = pts[farthest_point_sampling(pts, n)]
    elif len(pts) < n:
        pts = np.resize(pts, (n, 3))
    return pts.astype(np.float32)


def _split_categories(split: dict[str, Any], name: str) -> set[str]:
    test = set(split["test"]["categories"])
    if name == "test":
        return test
    cats = set(split[name]["categories"])
    overlap = cats & test
    if overlap:
        raise InvalidInputError(
            f"split.json lists test categories {sorted(overlap)} under {name!r}; training and test "
            "categories must be disjoint (zero-shot protocol)"
        )
    return cats


def load_tracks(
    data_dir: str | Path,
    split: str,
    config: NetworkConfig,
    text_encoder: TextEncoder,
    prior_library: PriorLibrary | None = None,
    *,
    min_points: int = 32,
    max_scenes: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[ObjectTrack]:
    """Every object track of one split of a synthetic dataset.

    Args:
        data_dir: dataset folder (`split.json`, `<scene>/NNNNNN-{color,depth,mask}.png`, `-meta.json`).
        split: `train`, `val` or `test`.
        config: sizes (crop_px, observed_points, prior_points).
        text_encoder: the frozen phi_T (`default_text_encoder()`); its width must equal config.text_dim.
        prior_library: where priors come from (default: a `PriorLibrary` on `text_encoder`).
        min_points: frames whose object has fewer depth points are marked invalid.
        max_scenes: read only the first scenes of the split.
        progress: called with (scenes done, scenes total) after each scene.
    """
    if split not in SPLITS:
        raise UnknownNameError("split", split, SPLITS)
    if text_encoder.dim != config.text_dim:
        raise InvalidInputError(
            f"text encoder width {text_encoder.dim} != config.text_dim {config.text_dim}; build the config "
            f"with text_dim={text_encoder.dim}"
        )
    info = read_split(data_dir)
    categories = _split_categories(info, split)
    library = prior_library or PriorLibrary(encoder=text_encoder)
    scenes = list(info[split]["scenes"])[:max_scenes]
    tokens_cache: dict[str, np.ndarray] = {}
    tracks: list[ObjectTrack] = []
    for i_scene, scene in enumerate(scenes):
        per_object: dict[int, dict[str, list[Any]]] = {}
        objects: dict[int, GroundTruthObject] = {}
        for sf in scene_frames(data_dir, scene):
            frame = sf.frame
            for obj in sf.ground_truth_objects:
                if obj.category not in categories:
                    continue
                oid = obj.instance_id
                objects.setdefault(oid, obj)
                rec = per_object.setdefault(oid, {k: [] for k in ("crop", "points", "R", "t", "size")})
                mask = sf.ground_truth_instance_mask == oid  # ground truth: plays the grounding step
                pts = (
                    observed_points(frame.depth_m, frame.intrinsics, mask, config.observed_points, min_points)
                    if mask.any()
                    else None
                )
                rec["points"].append(pts)
                rec["crop"].append(object_crop(frame.rgb, mask, config.crop_px) if pts is not None else None)
                rec["R"].append(obj.pose.R)
                rec["t"].append(obj.pose.t)
                rec["size"].append(obj.pose.size)
        for oid, rec in per_object.items():
            valid = np.array([p is not None for p in rec["points"]])
            if not valid.any():
                continue
            first = int(np.flatnonzero(valid)[0])
            # Invalid frames copy the nearest earlier valid frame (or the first valid one) and stay masked.
            last = first
            for f in range(len(valid)):
                if valid[f]:
                    last = f
                else:
                    rec["points"][f], rec["crop"][f] = rec["points"][last], rec["crop"][last]
            obj = objects[oid]
            prompt = obj.prompt
            if prompt not in tokens_cache:
                tokens_cache[prompt] = np.asarray(text_encoder.encode_tokens(prompt), dtype=np.float32)
            prior = library.generate(
                prompt, observation_points=rec["points"][first], n_points=config.prior_points
            )
            tracks.append(
                ObjectTrack(
                    scene=scene,
                    instance_id=oid,
                    category=obj.category,
                    prompt=prompt,
                    symmetry=obj.symmetry,
                    crops=np.stack(rec["crop"]),
                    points=np.stack(rec["points"]),
                    frame_valid=valid,
                    R_cam_obj=np.asarray(rec["R"], dtype=np.float32),
                    t_cam_obj_m=np.asarray(rec["t"], dtype=np.float32),
                    size_m=np.asarray(rec["size"], dtype=np.float32),
                    text_tokens=tokens_cache[prompt],
                    prior_points=np.asarray(prior.points, dtype=np.float32),
                )
            )
        if progress is not None:
            progress(i_scene + 1, len(scenes))
    log.info("loaded %d %s tracks from %d scenes of %s", len(tracks), split, len(scenes), data_dir)
    return tracks


def make_windows(
    tracks: Sequence[ObjectTrack], window: int, stride: int | None = None
) -> list[tuple[int, int]]:
    """(track index, first frame) of every window of `window` frames, one every `stride` (default `window`)
    frames; a track shorter than the window gives one (padded) window."""
    if window < 1:
        raise InvalidInputError(f"window must be >= 1, got {window}")
    step = window if stride is None else int(stride)
    if step < 1:
        raise InvalidInputError(f"stride must be >= 1, got {stride}")
    out = []
    for i, tr in enumerate(tracks):
        last_start = max(tr.num_frames - window, 0)
        starts = list(range(0, last_start + 1, step))
        if starts[-1] != last_start:
            starts.append(last_start)
        out += [(i, s) for s in starts if tr.frame_valid[s : s + window].any()]
    return out


def _jitter(crop: np.ndarray, rng: np.random.Generator, j: float) -> np.ndarray:
    """Colour jitter of a (S, S, 3) float crop in [0, 1]: brightness, contrast, saturation."""
    b, c, s = rng.uniform(1.0 - j, 1.0 + j, size=3)
    x = crop * b
    x = (x - x.mean()) * c + x.mean()
    grey = x.mean(axis=-1, keepdims=True)
    return np.clip((x - grey) * s + grey, 0.0, 1.0)


def _dropout(points: np.ndarray, rng: np.random.Generator, max_fraction: float) -> np.ndarray:
    n = len(points)
    drop = int(rng.uniform(0.0, max_fraction) * n)
    if drop == 0:
        return points
    keep = rng.permutation(n)[: n - drop]
    refill = rng.choice(keep, size=drop, replace=True)
    return points[np.concatenate([keep, refill])]


def collate(
    tracks: Sequence[ObjectTrack],
    windows: Sequence[tuple[int, int]],
    window: int,
    rng: np.random.Generator | None = None,
    augment: AugmentConfig | None = None,
) -> NetworkBatch:
    """Tensors of the given windows; with `rng` and `augment`, jittered colours and dropped points.

    Frames past a track's end are padded by repeating its last frame and marked invalid. d_t is computed from
    the (augmented) points with `robust_descriptor`.
    """
    if not windows:
        raise InvalidInputError("windows is empty; a batch needs at least one window")
    aug = augment if rng is not None else None
    B = len(windows)
    L = max(tracks[i].text_tokens.shape[0] for i, _ in windows)
    D = tracks[windows[0][0]].text_tokens.shape[1]
    crops, points, desc, valid, Rs, ts, sizes, priors, syms = [], [], [], [], [], [], [], [], []
    text = np.zeros((B, L, D), dtype=np.float32)
    text_valid = np.zeros((B, L), dtype=bool)
    for b, (ti, start) in enumerate(windows):
        tr = tracks[ti]
        idx = np.arange(start, start + window)
        in_range = idx < tr.num_frames
        idx = np.minimum(idx, tr.num_frames - 1)
        c = tr.crops[idx].astype(np.float32) / 255.0
        p = tr.points[idx]
        if aug is not None and rng is not None:
            c = np.stack([_jitter(ci, rng, aug.color_jitter) for ci in c])
            p = np.stack([_dropout(pi, rng, aug.max_point_dropout) for pi in p])
        crops.append(c.transpose(0, 3, 1, 2))
        points.append(p)
        desc.append(np.stack([robust_descriptor(pi).vector for pi in p]))
        valid.append(tr.frame_valid[idx] & in_range)
        Rs.append(tr.R_cam_obj[idx])
        ts.append(tr.t_cam_obj_m[idx])
        sizes.append(tr.size_m[idx])
        priors.append(tr.prior_points)
        syms.append(tr.symmetry)
        text[b, : tr.text_tokens.shape[0]] = tr.text_tokens
        text_valid[b, : tr.text_tokens.shape[0]] = True
    f32 = torch.float32
    return NetworkBatch(
        crops=torch.as_tensor(np.stack(crops), dtype=f32),
        points=torch.as_tensor(np.stack(points), dtype=f32),
        descriptors=torch.as_tensor(np.stack(desc), dtype=f32),
        prior_points=torch.as_tensor(np.stack(priors), dtype=f32),
        text_tokens=torch.as_tensor(text),
        text_valid=torch.as_tensor(text_valid),
        frame_valid=torch.as_tensor(np.stack(valid)),
        R_cam_obj=torch.as_tensor(np.stack(Rs), dtype=f32),
        t_cam_obj_m=torch.as_tensor(np.stack(ts), dtype=f32),
        size_m=torch.as_tensor(np.stack(sizes), dtype=f32),
        symmetry=symmetry_codes(syms),
    )
