"""Reading the synthetic 9-DoF dataset (DESIGN.md "Synthetic dataset"), for training and benchmarks.

Layout: `DIR/split.json` and `DIR/<scene>/<frame:06d>-color.png`, `-depth.png` (uint16), `-mask.png`
(instance ids), `-meta.json` (`K`, `T_world_cam`, `depth_scale_m`, `objects: [{id, category, prompt, R, t,
size, symmetry, ...}]`, all 9-DoF in the camera frame). Everything read here is ground truth and is named
so; library code that estimates never calls it (training and `prompose_grasp.eval` do).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["GroundTruthObject", "SyntheticFrame", "read_split", "scene_frames"]


@dataclass(frozen=True, eq=False)
class GroundTruthObject:
    """One object's ground truth in one frame (benchmarks and training only).

    Attributes:
        instance_id: its value in the frame's instance mask.
        category, prompt: the object's category and the text that names it.
        pose: the amodal 9-DoF box in the camera frame.
        symmetry: the symmetry tag of its family ("none", "y_continuous", ...).
        handle_visible: for objects with a handle (mugs), whether the handle is seen in this frame (the NOCS
            protocol's `gt_handle_visibility`); True when the dataset does not record it.
        meta: the raw meta entry.
    """

    instance_id: int
    category: str
    prompt: str
    pose: Pose9D
    symmetry: str
    handle_visible: bool
    meta: dict[str, Any]


@dataclass(frozen=True, eq=False)
class SyntheticFrame:
    """A frame of the dataset: the `RGBDFrame` a user's camera would give, plus its ground truth.

    `frame.T_base_cam` is the dataset's `T_world_cam` (the world frame plays the robot base: a robot knows its
    camera's pose from forward kinematics and hand-eye calibration).
    """

    scene: str
    index: int
    frame: RGBDFrame
    ground_truth_instance_mask: np.ndarray
    ground_truth_objects: tuple[GroundTruthObject, ...]


def read_split(data: str | Path) -> dict[str, Any]:
    """`DIR/split.json`: {split: {"scenes": [...], "categories": [...]}}."""
    path = Path(data) / "split.json"
    if not path.is_file():
        raise InvalidInputError(f"{path} not found: is {data} a dataset written by `python -m sim.dataset`?")
    return json.loads(path.read_text())


def _png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InvalidInputError(f"{path}: missing or unreadable image")
    return img


def scene_frames(data: str | Path, scene: str, max_frames: int | None = None) -> Iterator[SyntheticFrame]:
    """The frames of one scene, in order."""
    folder = Path(data) / scene
    metas = sorted(folder.glob("*-meta.json"))
    if not metas:
        raise InvalidInputError(f"{folder}: no frames (NNNNNN-meta.json)")
    for meta_path in metas[:max_frames]:
        meta = json.loads(meta_path.read_text())
        stem = str(meta_path)[: -len("-meta.json")]
        bgr = _png(Path(stem + "-color.png"))
        depth = _png(Path(stem + "-depth.png")).astype(np.float32) * np.float32(meta["depth_scale_m"])
        K = np.asarray(meta["K"], dtype=np.float64)
        intrinsics = CameraIntrinsics(
            K[0, 0], K[1, 1], K[0, 2], K[1, 2], int(meta["width"]), int(meta["height"])
        )
        frame = RGBDFrame(
            rgb=np.ascontiguousarray(bgr[..., ::-1]),
            depth_m=depth,
            intrinsics=intrinsics,
            timestamp_s=float(meta["frame"]),
            T_base_cam=np.asarray(meta["T_world_cam"], dtype=np.float64),
        )
        objects = tuple(
            GroundTruthObject(
                instance_id=int(o["id"]),
                category=str(o["category"]),
                prompt=str(o["prompt"]),
                pose=Pose9D(o["R"], o["t"], o["size"]),
                symmetry=str(o["symmetry"]),
                handle_visible=bool(o.get("handle_visible", True)),
                meta=o,
            )
            for o in meta["objects"]
        )
        yield SyntheticFrame(scene, int(meta["frame"]), frame, _png(Path(stem + "-mask.png")), objects)
