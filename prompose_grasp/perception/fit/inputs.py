"""Checks of `fit_pose`'s arguments: clear errors on wrong shapes, NaN/inf, points behind the camera, too few
points, an up direction and a support plane that disagree."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.fit.observation import SceneView
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.prior import SYMMETRIES, ShapePrior


@dataclass(frozen=True)
class _Inputs:
    """`fit_pose`'s arguments, checked: the config, the points as (N, 3) float64, the unit up direction and
    the unit-normal support plane (each None when not given; a plane's normal is the up direction)."""

    cfg: FitConfig
    pts: np.ndarray
    up: np.ndarray | None
    plane: tuple[np.ndarray, float] | None


def _check_inputs(
    points_cam: ArrayLike,
    prior: ShapePrior,
    config: FitConfig | None,
    up_cam: ArrayLike | None,
    init: Pose9D | None,
    support_plane_cam: ArrayLike | None,
    scene: SceneView | None,
) -> _Inputs:
    """`fit_pose`'s arguments checked and normalised (see its docstring), or `InvalidInputError`."""
    cfg = FitConfig() if config is None else config
    if not isinstance(cfg, FitConfig):
        raise InvalidInputError(f"config must be a FitConfig, got {type(cfg).__name__}")
    _check_prior(prior)
    pts_all = _check_points(points_cam, cfg.min_points)
    up = _check_unit(up_cam, "up_cam")
    plane = _check_plane(support_plane_cam, up)
    if plane is not None:
        up = plane[0]
    if init is not None and not isinstance(init, Pose9D):
        raise InvalidInputError(f"init must be a Pose9D or None, got {type(init).__name__}")
    if scene is not None and not isinstance(scene, SceneView):
        raise InvalidInputError(f"scene must be a SceneView or None, got {type(scene).__name__}")
    return _Inputs(cfg, pts_all, up, plane)


def _check_points(points_cam: ArrayLike, min_points: int) -> np.ndarray:
    P = np.asarray(points_cam)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points_cam must have shape (N, 3) in metres, got {P.shape}")
    if not np.issubdtype(P.dtype, np.number) or np.issubdtype(P.dtype, np.complexfloating):
        raise InvalidInputError(f"points_cam must be real numbers (metres), got dtype {P.dtype}")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InvalidInputError(
            "points_cam holds NaN or inf; drop pixels without a depth reading first (back_project does)"
        )
    if len(P) < min_points:
        raise InvalidInputError(
            f"points_cam has {len(P)} points; the fit needs at least {min_points} (FitConfig.min_points)"
        )
    if np.any(P[:, 2] <= 0.0):
        raise InvalidInputError("points_cam must lie in front of the camera (z > 0, OpenCV camera frame)")
    return P


def _check_unit(v: ArrayLike | None, name: str) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} must be a finite (3,) direction in the camera frame, got {v!r}")
    n = float(np.linalg.norm(a))
    if n < 1e-9:
        raise InvalidInputError(f"{name} must be a non-zero direction, got {v!r}")
    return a / n


def _check_plane(plane: ArrayLike | None, up: np.ndarray | None) -> tuple[np.ndarray, float] | None:
    if plane is None:
        return None
    a = np.asarray(plane, dtype=np.float64)
    if a.shape != (4,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(
            f"support_plane_cam must be a finite (4,) plane (nx, ny, nz, d) with n.x + d = 0, got {plane!r}"
        )
    n = float(np.linalg.norm(a[:3]))
    if n < 1e-9:
        raise InvalidInputError("support_plane_cam has a zero normal")
    normal, d = a[:3] / n, float(a[3]) / n
    if up is not None and float(normal @ up) < math.cos(math.radians(5.0)):
        raise InvalidInputError(
            "up_cam and the normal of support_plane_cam disagree by more than 5 degrees; pass one of them "
            "or make them agree (the plane normal must point up, towards the object)"
        )
    return normal, d


def _check_prior(prior: ShapePrior) -> None:
    if not isinstance(prior, ShapePrior):
        raise InvalidInputError(f"prior must be a ShapePrior, got {type(prior).__name__}")
    if prior.symmetry not in SYMMETRIES:
        raise InvalidInputError(f"prior.symmetry {prior.symmetry!r} is not one of {SYMMETRIES}")
    if len(prior.points) < 4 or prior.points.shape != prior.normals.shape:
        raise InvalidInputError("prior needs >= 4 points with one normal each")
