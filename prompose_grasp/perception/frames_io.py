"""Reading RGB-D frames from image files: one pair, or a recorded `NNNNNN-color.png` / `-depth.png` folder."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import check_depth_units
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["decode_image", "frame_from_images", "list_sequence", "load_rgbd"]

_FRAME_RE = re.compile(r"^(\d+)-color\.(png|jpg|jpeg)$")


def load_rgbd(
    rgb_path: str | Path,
    depth_path: str | Path,
    depth_scale_m: float,
    fx_fy_cx_cy: tuple[float, float, float, float],
    timestamp_s: float = 0.0,
) -> RGBDFrame:
    """Read a colour image and a registered uint16 depth PNG into an `RGBDFrame`.

    Args:
        rgb_path: 8-bit colour image (PNG/JPEG).
        depth_path: single-channel uint16 PNG; depth [m] = value * depth_scale_m, 0 = no reading.
        depth_scale_m: metres per depth unit (0.001 for millimetre PNGs).
        fx_fy_cx_cy: pinhole intrinsics [px] of both images.
    Raises:
        InvalidInputError: a file is missing or unreadable, the images disagree in size, the depth is not a
            single-channel 16-bit image, the scaled depth is no distance an RGB-D camera measures (a
            millimetre PNG read with scale 1: the message names the scale), or the intrinsics are not a
            camera.
    """
    _check_scale(depth_scale_m)
    bgr = _read(rgb_path, cv2.IMREAD_COLOR)
    depth_raw = _read(depth_path, cv2.IMREAD_UNCHANGED)
    return frame_from_images(
        np.ascontiguousarray(bgr[..., ::-1]),
        depth_raw,
        depth_scale_m,
        fx_fy_cx_cy,
        timestamp_s,
        rgb_name=str(rgb_path),
        depth_name=str(depth_path),
    )


def _check_scale(depth_scale_m: float) -> float:
    scale = float(depth_scale_m)
    if not np.isfinite(scale) or scale <= 0:
        raise InvalidInputError(f"depth scale must be > 0 metres per unit, got {depth_scale_m}")
    return scale


def frame_from_images(
    rgb: np.ndarray,
    depth_raw: np.ndarray,
    depth_scale_m: float,
    fx_fy_cx_cy: tuple[float, float, float, float],
    timestamp_s: float = 0.0,
    *,
    rgb_name: str = "rgb",
    depth_name: str = "depth",
) -> RGBDFrame:
    """An `RGBDFrame` from decoded images, checked as `load_rgbd` checks files (the same messages, naming
    `rgb_name` / `depth_name` where `load_rgbd` names the files).

    Args:
        rgb: (H, W, 3) uint8, RGB order.
        depth_raw: (H, W) uint16 (depth [m] = value * depth_scale_m, 0 = no reading), or (H, W) float32
            metres (`depth_scale_m` is then not applied).
        depth_scale_m: metres per depth unit of a uint16 depth.
        fx_fy_cx_cy: pinhole intrinsics [px] of both images.
    """
    scale = _check_scale(depth_scale_m)
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InvalidInputError(
            f"{rgb_name}: colour must be (H, W, 3) uint8, got shape {rgb.shape} {rgb.dtype}"
        )
    depth_raw = np.asarray(depth_raw)
    if depth_raw.ndim != 2 or depth_raw.dtype not in (np.uint16, np.float32):
        raise InvalidInputError(
            f"{depth_name}: depth must be a single-channel 16-bit PNG, got shape {depth_raw.shape} "
            f"{depth_raw.dtype}"
        )
    if depth_raw.shape != rgb.shape[:2]:
        raise InvalidInputError(
            f"colour image {rgb.shape[:2]} and depth image {depth_raw.shape} (rows, cols) differ; "
            "the depth must be registered to the colour image"
        )
    fx, fy, cx, cy = (float(v) for v in fx_fy_cx_cy)
    intrinsics = CameraIntrinsics(fx, fy, cx, cy, width=rgb.shape[1], height=rgb.shape[0])
    if depth_raw.dtype == np.float32:
        depth_m = depth_raw.copy()
        check_depth_units(depth_m, depth_name)
    else:
        depth_m = depth_raw.astype(np.float32) * np.float32(scale)
        try:
            check_depth_units(depth_m)
        except InvalidInputError as exc:  # the scale is the likely culprit: say which one was used
            raise InvalidInputError(
                f"{depth_name}: {exc}; the depth scale was {scale:g} m per unit "
                "(a millimetre PNG takes 0.001)"
            ) from None
    return RGBDFrame(
        rgb=np.ascontiguousarray(rgb),
        depth_m=depth_m,
        intrinsics=intrinsics,
        timestamp_s=float(timestamp_s),
    )


def decode_image(data: bytes, name: str, depth: bool = False) -> np.ndarray:
    """A PNG / JPEG file's bytes decoded: (H, W, 3) uint8 RGB, or with `depth` the image unchanged (a 16-bit
    PNG stays uint16). `name` is what an error message calls it."""
    flags = cv2.IMREAD_UNCHANGED if depth else cv2.IMREAD_COLOR
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags) if data else None
    if img is None:
        raise InvalidInputError(f"{name}: not a readable image")
    return img if depth else np.ascontiguousarray(img[..., ::-1])


def list_sequence(folder: str | Path) -> list[tuple[int, Path, Path]]:
    """(index, colour path, depth path) of every `NNNNNN-color.png` with its `NNNNNN-depth.png`, in order."""
    root = Path(folder)
    if not root.is_dir():
        raise InvalidInputError(f"{root} is not a folder of NNNNNN-color.png / NNNNNN-depth.png frames")
    frames = []
    for path in sorted(root.iterdir()):
        m = _FRAME_RE.match(path.name)
        if m:
            depth = root / f"{m.group(1)}-depth.png"
            if not depth.is_file():
                raise InvalidInputError(f"{path.name} has no matching {depth.name} in {root}")
            frames.append((int(m.group(1)), path, depth))
    if not frames:
        raise InvalidInputError(f"no NNNNNN-color.png frames in {root}")
    return frames


def _read(path: str | Path, flags: int) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    img = cv2.imread(str(p), flags)
    if img is None:
        raise InvalidInputError(f"{p}: not a readable image")
    return img
