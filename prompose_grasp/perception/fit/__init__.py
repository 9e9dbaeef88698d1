"""Metric 9-DoF fit of a canonical shape prior to observed points (test-time L_geo; docs/fit.md).

`fit_pose` (in `core`) runs the steps of the other modules: `inputs`, `observation`, `hypotheses`, `solver`
on the `objective` (parameters in `problem`), `handle`, `surface`, `symmetry`; `types` holds the settings
and the result.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.fit.core import fit_pose
    from prompose_grasp.perception.fit.handle import protrusion_points
    from prompose_grasp.perception.fit.observation import SceneView, mask_coverage, visible_prior_mask
    from prompose_grasp.perception.fit.surface import grow_to_seen, seen_surface
    from prompose_grasp.perception.fit.symmetry import canonicalize_symmetry
    from prompose_grasp.perception.fit.types import FitConfig, FitResult, FitStage

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.fit.core": ("fit_pose",),
        "prompose_grasp.perception.fit.handle": ("protrusion_points",),
        "prompose_grasp.perception.fit.observation": ("SceneView", "mask_coverage", "visible_prior_mask"),
        "prompose_grasp.perception.fit.surface": ("grow_to_seen", "seen_surface"),
        "prompose_grasp.perception.fit.symmetry": ("canonicalize_symmetry",),
        "prompose_grasp.perception.fit.types": ("FitConfig", "FitResult", "FitStage"),
    },
    submodules=(
        "core",
        "handle",
        "hypotheses",
        "inputs",
        "objective",
        "observation",
        "problem",
        "solver",
        "surface",
        "symmetry",
        "types",
    ),
)

__all__ = [
    "FitConfig",
    "FitResult",
    "FitStage",
    "SceneView",
    "canonicalize_symmetry",
    "fit_pose",
    "grow_to_seen",
    "mask_coverage",
    "protrusion_points",
    "seen_surface",
    "visible_prior_mask",
]
