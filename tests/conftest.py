"""Suite-wide settings: MuJoCo renders headless (EGL) unless the environment says otherwise, so `pytest` run
directly behaves as `make test` (a test module that renders may be collected before the sim tests' own
conftest sets it, and MuJoCo reads the variable once, at its first import)."""

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_unconfigure(config):
    """Stop the local Ray cluster that the cluster tests started (one for the whole test run, `ray_local`)."""
    import sys

    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        ray.shutdown()


@pytest.fixture
def ray_local():
    """A real local Ray cluster of 2 CPUs, started once for the whole test run (a cluster start costs seconds)
    and stopped in `pytest_unconfigure`; skipped without the `cluster` extra."""
    ray = pytest.importorskip("ray", reason="the cluster tests need the `cluster` extra (ray)")
    if not ray.is_initialized():
        from prompose_grasp.eval.sweep import RayExecutor

        RayExecutor("local:2")  # the way `--ray local:2` starts it
    return ray
