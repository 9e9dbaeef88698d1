"""Placing objects on supports: upright poses, footprints, and random non-overlapping placements."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import (
    make_T,
)
from sim.objects import ObjectAsset
from sim.world import Support

__all__ = ["footprint_radius_m", "sample_upright_placements", "upright_pose"]


def upright_pose(
    asset: ObjectAsset,
    support: Support,
    xy_m: ArrayLike = (0.0, 0.0),
    yaw_rad: float = 0.0,
    clearance_m: float = 0.0,
) -> np.ndarray:
    """T_world_obj (4, 4) standing the object upright (canonical +y along the surface's z) on a support.

    `xy_m` (2,) is the position on the surface in the surface frame [m]; `yaw_rad` turns about the surface z;
    `clearance_m` lifts the box bottom above the surface.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise InvalidInputError(f"xy_m must be (2,) finite, got {xy_m!r}")
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    R_yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    R_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # obj +y -> surface +z
    t = np.array([xy[0], xy[1], asset.size[1] / 2.0 + clearance_m])
    return support.T_world_surface @ make_T(R_yaw @ R_up, t)


def footprint_radius_m(asset: ObjectAsset) -> float:
    """Radius [m] of the disc covering the object's upright footprint (its x-z extents) at any yaw."""
    return 0.5 * math.hypot(asset.size[0], asset.size[2])


def sample_upright_placements(
    assets: Sequence[ObjectAsset],
    support: Support,
    rng: np.random.Generator,
    margin_m: float = 0.01,
    region_half_extents_m: ArrayLike | None = None,
    region_centre_m: ArrayLike = (0.0, 0.0),
    max_tries: int = 500,
    clearance_m: float = 0.0,
) -> list[np.ndarray]:
    """Non-overlapping upright poses with random yaw for `assets` on a support (footprint discs + margin).

    Raises InvalidInputError when they cannot all be fitted in `max_tries` draws per object.
    """
    half = np.asarray(
        support.half_extents_xy_m if region_half_extents_m is None else region_half_extents_m, float
    )
    centre = np.asarray(region_centre_m, dtype=np.float64)
    placed: list[tuple[np.ndarray, float]] = []
    poses: list[np.ndarray] = [np.eye(4)] * len(assets)
    # Largest first: small objects fill the gaps the big ones leave (random sequential packing).
    order = sorted(range(len(assets)), key=lambda i: -footprint_radius_m(assets[i]))
    for k in order:
        asset = assets[k]
        r = footprint_radius_m(asset)
        lim = half - r - margin_m
        if np.any(lim < 0):
            raise InvalidInputError(
                f"object {k} ({asset.category}, footprint radius {r:.3f} m) does not fit the region"
            )
        for _ in range(max_tries):
            xy = centre + rng.uniform(-lim, lim)
            if all(np.linalg.norm(xy - p) >= r + rp + margin_m for p, rp in placed):
                break
        else:
            raise InvalidInputError(
                f"could not place object {k} ({asset.category}) without overlap on {support.name!r}"
            )
        placed.append((xy, r))
        poses[k] = upright_pose(asset, support, xy, float(rng.uniform(-math.pi, math.pi)), clearance_m)
    return poses
