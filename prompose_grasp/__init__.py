"""prompose_grasp: language-commanded pick-and-place from RGB-D frames.

The curated public API lives here; subpackages hold the rest:

- `prompose_grasp.geometry`: SE(3), `Pose9D`, oriented-box IoU, point clouds, Chamfer distance
  (numpy + scipy only).
- `prompose_grasp.eval`: NOCS-compatible 9-DoF pose metrics (`compute_nocs_map`).
"""

from importlib.metadata import version as _version

from prompose_grasp.errors import (
    CameraError,
    InvalidInputError,
    MissingDependencyError,
    PromposeError,
    UnknownNameError,
    UnreachableError,
    UnsafeCommandError,
)
from prompose_grasp.geometry import Pose9D

__version__ = _version("prompose-grasp")

__all__ = [
    "CameraError",
    "InvalidInputError",
    "MissingDependencyError",
    "Pose9D",
    "PromposeError",
    "UnknownNameError",
    "UnreachableError",
    "UnsafeCommandError",
    "__version__",
]
