"""Metric 9-DoF fit of a canonical shape prior to observed points (test-time L_geo; docs/fit.md)."""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.fit.core import (
        FitConfig,
        FitResult,
        FitStage,
        SceneView,
        canonicalize_symmetry,
        fit_pose,
        grow_to_seen,
        mask_coverage,
        protrusion_points,
        seen_surface,
        visible_prior_mask,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.fit.core": (
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
        ),
    },
    submodules=("core",),
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
