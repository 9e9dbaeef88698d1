"""Shared helpers for the sim tests: a back-projection written independently of sim, a seeded rng."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


def back_project(
    depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float, mask: np.ndarray
) -> np.ndarray:
    """(N, 3) camera-frame points [m] of the masked pixels with depth > 0 (pixel centres at integers)."""
    v, u = np.nonzero(mask & (depth_m > 0))
    z = depth_m[v, u].astype(np.float64)
    return np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
