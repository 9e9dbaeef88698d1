"""Pictures a person looks at: colourised depth, ground-truth box overlays, tiles of camera views."""

from __future__ import annotations

import cv2
import numpy as np

from prompose_grasp.geometry.boxes import BOX_EDGES, box_corners
from prompose_grasp.geometry.camera import CameraIntrinsics

__all__ = ["colorize_depth", "draw_boxes", "tile"]


def colorize_depth(
    depth_m: np.ndarray, near_m: float | None = None, far_m: float | None = None
) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a depth image [m] (turbo colour map; black = no reading)."""
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


def draw_boxes(
    color: np.ndarray,
    K: CameraIntrinsics,
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    labels: list[str] | None = None,
) -> np.ndarray:
    """Draw 9-DoF boxes (R_cam_obj (3, 3), t (3,) [m], size (3,) [m]) on a copy of an RGB image."""
    out = np.ascontiguousarray(color.copy())
    for i, (R, t, size) in enumerate(boxes):
        corners = box_corners(size) @ np.asarray(R).T + np.asarray(t)
        if np.any(corners[:, 2] <= 1e-3):
            continue
        uv = corners[:, :2] / corners[:, 2:] * [K.fx, K.fy] + [K.cx, K.cy]
        hue = (i * 47) % 180
        rgb = cv2.cvtColor(np.uint8([[[hue, 220, 255]]]), cv2.COLOR_HSV2RGB)[0, 0].tolist()
        for a, b in BOX_EDGES:
            cv2.line(
                out,
                tuple(np.round(uv[a]).astype(int)),
                tuple(np.round(uv[b]).astype(int)),
                rgb,
                1,
                cv2.LINE_AA,
            )
        if labels:
            top = uv[np.argmin(uv[:, 1])]
            cv2.putText(out, labels[i], (int(top[0]), int(top[1]) - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.4, rgb, 1)
    return out


def tile(images: list[np.ndarray]) -> np.ndarray:
    """Stack RGB images in rows of two, padding to a common size with black."""
    h = max(i.shape[0] for i in images)
    w = max(i.shape[1] for i in images)
    padded = [np.pad(i, ((0, h - i.shape[0]), (0, w - i.shape[1]), (0, 0))) for i in images]
    if len(padded) % 2:
        padded.append(np.zeros_like(padded[0]))
    rows = [np.hstack(padded[k : k + 2]) for k in range(0, len(padded), 2)]
    return np.vstack(rows)
