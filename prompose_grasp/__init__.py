"""prompose_grasp: language-commanded pick-and-place from RGB-D frames.

The curated public API lives here; subpackages hold the rest:

- `prompose_grasp.geometry`: SE(3), `Pose9D`, oriented-box IoU, point clouds, Chamfer distance
  (numpy + scipy only).
- `prompose_grasp.eval`: NOCS-compatible 9-DoF pose metrics (`compute_nocs_map`).
- `prompose_grasp.perception`: ProM-Pose, `ProMPose.default().estimate(frame, "the red mug")`.
- `prompose_grasp.grasp`: parallel-jaw and suction grasps from 9-DoF boxes and meshes, python-fcl scenes,
  IK-feasible ranking (`plan_grasps`), place planning, collision-checked pick-and-place motions.
- `prompose_grasp.pipeline`: `PickAndPlace(...).run("put the mug in the bin") -> PickOutcome`.
- `prompose_grasp.robot`: UR models (Pinocchio + MuJoCo from one DH table), FK/IK, trajectories, the
  `Arm` / `Gripper` / `RGBDCamera` interfaces and the shared command validator.
- `prompose_grasp.service`: the estimator kept loaded behind HTTP (`prompose-grasp serve`) and its client.
- `prompose_grasp.viz`: rerun recordings of a run (`RerunRecorder`, extra `viz`); `Recorder` is the seam the
  estimator and the loop record into (a no-op by default).

Importing the package loads none of them: each name below (and each subpackage) resolves on first access
(PEP 562, `prompose_grasp._lazy`), so `import prompose_grasp.geometry` costs numpy and scipy, not torch or
MuJoCo.
"""

from importlib.metadata import version as _version
from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach
from prompose_grasp.errors import (
    AmbiguousObjectError,
    CameraError,
    DeviceNotConnectedError,
    InvalidInputError,
    MissingDependencyError,
    NoFeasibleGrasp,
    ObjectNotFoundError,
    PromposeError,
    UnknownNameError,
    UnreachableError,
    UnsafeCommandError,
)

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.geometry import Pose9D
    from prompose_grasp.grasp import GraspConfig, ObjectModel, Plane, plan_grasps
    from prompose_grasp.perception import Estimate, ProMPose
    from prompose_grasp.pipeline import PickAndPlace, PickConfig, PickOutcome
    from prompose_grasp.recorder import Recorder
    from prompose_grasp.robot import (
        Arm,
        CommandValidator,
        FakeArm,
        Gripper,
        IKResult,
        RGBDCamera,
        RGBDFrame,
        RobotModel,
        load_robot,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.geometry": ("Pose9D",),
        "prompose_grasp.grasp": (
            "GraspConfig",
            "ObjectModel",
            "Plane",
            "plan_grasps",
        ),
        "prompose_grasp.perception": (
            "Estimate",
            "ProMPose",
        ),
        "prompose_grasp.pipeline": (
            "PickAndPlace",
            "PickConfig",
            "PickOutcome",
        ),
        "prompose_grasp.recorder": ("Recorder",),
        "prompose_grasp.robot": (
            "Arm",
            "CommandValidator",
            "FakeArm",
            "Gripper",
            "IKResult",
            "RGBDCamera",
            "RGBDFrame",
            "RobotModel",
            "load_robot",
        ),
    },
    submodules=(
        "cli",
        "errors",
        "eval",
        "geometry",
        "grasp",
        "hardware",
        "perception",
        "pipeline",
        "robot",
        "service",
        "viz",
    ),
)

__version__ = _version("prompose-grasp")

__all__ = [
    "AmbiguousObjectError",
    "Arm",
    "CameraError",
    "CommandValidator",
    "DeviceNotConnectedError",
    "Estimate",
    "FakeArm",
    "GraspConfig",
    "Gripper",
    "IKResult",
    "InvalidInputError",
    "MissingDependencyError",
    "NoFeasibleGrasp",
    "ObjectModel",
    "ObjectNotFoundError",
    "PickAndPlace",
    "PickConfig",
    "PickOutcome",
    "Plane",
    "Pose9D",
    "ProMPose",
    "PromposeError",
    "RGBDCamera",
    "RGBDFrame",
    "Recorder",
    "RobotModel",
    "UnknownNameError",
    "UnreachableError",
    "UnsafeCommandError",
    "__version__",
    "load_robot",
    "plan_grasps",
]
