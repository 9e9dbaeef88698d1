"""The dry-run tests render the MuJoCo scene headless: EGL, set before anything imports mujoco."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
