"""Suite-wide settings: MuJoCo renders headless (EGL) unless the environment says otherwise, so `pytest` run
directly behaves as `make test` (a test module that renders may be collected before the sim tests' own
conftest sets it, and MuJoCo reads the variable once, at its first import)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
