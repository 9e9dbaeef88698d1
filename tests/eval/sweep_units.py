"""Unit functions for the sweep tests, in a module of their own so that Ray workers import them by name."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def seeded_unit(payload: dict) -> dict:
    """A unit whose result depends on its seed only: a few draws and their sum (floats, ints, strings)."""
    rng = np.random.default_rng([payload["seed"], 7])
    draws = rng.normal(size=5)
    return {
        "seed": payload["seed"],
        "draws": draws.tolist(),
        "sum": float(draws.sum()),
        "tag": f"u{payload['seed']}",
    }


def dies_once_unit(payload: dict) -> dict:
    """The worker process ends without an answer on the first attempt (as a SIGKILL or the OOM killer would:
    `os._exit`, no exception, no cleanup); a marker file left behind makes the retry succeed."""
    marker = Path(payload["marker"])
    if not marker.exists():
        marker.write_text("attempted")
        os._exit(9)
    return seeded_unit(payload)


def raising_unit(payload: dict) -> dict:
    """Always raises: must end as a typed failure row while the other units finish."""
    if payload.get("fail"):
        raise KeyError(f"unit {payload['seed']} has no such key")
    return seeded_unit(payload)


def threads_unit(payload: dict) -> dict:
    """What a unit sees of the thread pinning."""
    return {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "LP_NUM_THREADS", "MUJOCO_GL")}


def always_dies_unit(payload: dict) -> dict:
    """The worker process ends on every attempt."""
    os._exit(9)
