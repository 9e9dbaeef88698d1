"""Metric 9-DoF fit of a canonical shape prior to observed points (test-time L_geo; docs/fit.md)."""

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
