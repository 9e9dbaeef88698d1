"""Pictures a person would rather look at than read: 9-DoF boxes and masks drawn on the colour image."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.boxes import BOX_EDGES
from prompose_grasp.geometry.camera import CameraIntrinsics

__all__ = ["ESTIMATE_RGB", "GROUND_TRUTH_RGB", "colorize_depth", "distinct_colors", "draw_poses"]

#: The paper's Figure 7 colours: estimates in green, ground truth in red.
ESTIMATE_RGB = (40, 220, 60)
GROUND_TRUTH_RGB = (230, 40, 40)


def distinct_colors(n: int) -> list[tuple[int, int, int]]:
    """`n` saturated RGB colours with hues spread by the golden angle (neighbours in a list differ)."""
    hues = (np.arange(n) * 47) % 180  # OpenCV hue is 0..179; 47 steps visit all hues before repeating
    hsv = np.stack([hues, np.full(n, 220), np.full(n, 255)], axis=1).astype(np.uint8)[None]
    return [(int(r), int(g), int(b)) for r, g, b in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0]]


def colorize_depth(
    depth_m: np.ndarray, near_m: float | None = None, far_m: float | None = None
) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a depth image [m]: turbo colour map, near = red, black = no reading."""
    d = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(d) & (d > 0)
    if not valid.any():
        return np.zeros((*d.shape, 3), np.uint8)
    lo = float(np.percentile(d[valid], 1)) if near_m is None else near_m
    hi = float(np.percentile(d[valid], 99)) if far_m is None else far_m
    scaled = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
    bgr = cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[~valid] = 0
    return bgr[..., ::-1].copy()


def draw_poses(
    rgb: np.ndarray,
    intrinsics: CameraIntrinsics,
    poses: Sequence[Pose9D],
    colors: Sequence[tuple[int, int, int]] | None = None,
    labels: Sequence[str] | None = None,
    masks: Sequence[np.ndarray] | None = None,
    thickness: int = 2,
) -> np.ndarray:
    """Draw the edges of 9-DoF boxes (and optionally tint masks) on a copy of an RGB image.

    Args:
        rgb: (H, W, 3) uint8.
        intrinsics: the camera of `rgb`; poses are in its (OpenCV) frame.
        poses: boxes to draw; a box with a corner behind the camera is skipped.
        colors: one RGB triple per pose (default: all `ESTIMATE_RGB`).
        labels: optional text per pose, written above the box.
        masks: optional (H, W) bool per pose, tinted with the pose's colour at 40 %.
        thickness: line width [px].
    Returns:
        (H, W, 3) uint8 RGB.
    """
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInputError(f"rgb must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    out = np.ascontiguousarray(img.copy())
    colors = list(colors) if colors is not None else [ESTIMATE_RGB] * len(poses)
    for i, mask in enumerate(masks or []):
        m = np.asarray(mask, dtype=bool)
        if m.shape != out.shape[:2]:
            raise InvalidInputError(f"mask {i} must be {out.shape[:2]}, got {m.shape}")
        out[m] = (0.6 * out[m] + 0.4 * np.asarray(colors[i], dtype=np.float64)).astype(np.uint8)
    placed: list[tuple[int, int, int, int]] = []  # labels drawn so far: x, baseline y, width, height [px]
    for i, pose in enumerate(poses):
        corners = pose.corners()
        if np.any(corners[:, 2] <= 1e-3):  # behind or on the camera plane: the projection is meaningless
            continue
        uv = np.round(intrinsics.project(corners)).astype(int)
        color = tuple(int(c) for c in colors[i])
        for a, b in BOX_EDGES:
            cv2.line(out, tuple(uv[a]), tuple(uv[b]), color, thickness, cv2.LINE_AA)
        if labels:
            top = uv[np.argmin(uv[:, 1])]
            (w, h), _ = cv2.getTextSize(labels[i], cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
            x, y = int(top[0]), int(top[1]) - 4
            # boxes of the same object (estimate and ground truth) share a top corner: stack their labels
            while any(x < px + pw and px < x + w and y - h < py and py - ph < y for px, py, pw, ph in placed):
                y -= h + 4
            placed.append((x, y, w, h))
            cv2.putText(out, labels[i], (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, color, 1, cv2.LINE_AA)
    return out
