"""Tiles of camera views (box overlays and depth colouring are `prompose_grasp.perception.overlay`)."""

from __future__ import annotations

import numpy as np

__all__ = ["tile"]


def tile(images: list[np.ndarray]) -> np.ndarray:
    """Stack RGB images in rows of two, padding to a common size with black."""
    h = max(i.shape[0] for i in images)
    w = max(i.shape[1] for i in images)
    padded = [np.pad(i, ((0, h - i.shape[0]), (0, w - i.shape[1]), (0, 0))) for i in images]
    if len(padded) % 2:
        padded.append(np.zeros_like(padded[0]))
    rows = [np.hstack(padded[k : k + 2]) for k in range(0, len(padded), 2)]
    return np.vstack(rows)
