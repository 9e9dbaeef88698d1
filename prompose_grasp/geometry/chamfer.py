"""Bidirectional Chamfer distance between point clouds (the paper's L_geo, section 3.7), using cKDTree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from prompose_grasp.geometry.pointcloud import as_points

__all__ = ["ChamferResult", "chamfer_distance", "nearest_neighbor_distances"]


@dataclass(frozen=True)
class ChamferResult:
    """Both directions of the Chamfer distance and their sum.

    Attributes:
        a_to_b: mean over a of the (squared) distance to the nearest point of b [m^2, or m if not squared].
        b_to_a: mean over b of the (squared) distance to the nearest point of a.
        total: a_to_b + b_to_a (the paper's per-frame L_geo when squared).
    """

    a_to_b: float
    b_to_a: float
    total: float


def nearest_neighbor_distances(query: ArrayLike, reference: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """For each of the (N, 3) `query` points, the Euclidean distance [m] to the nearest of the (M, 3)
    `reference` points and that point's index. Returns ((N,) float64, (N,) intp)."""
    Q = as_points(query, "query")
    R = as_points(reference, "reference")
    dist, idx = cKDTree(R).query(Q, k=1)
    return np.asarray(dist, dtype=np.float64), np.asarray(idx, dtype=np.intp)


def chamfer_distance(A: ArrayLike, B: ArrayLike, squared: bool = True) -> ChamferResult:
    """Bidirectional Chamfer distance between (N, 3) `A` and (M, 3) `B` [m].

    With `squared=True` (default, the paper's L_geo) each direction is the mean of squared nearest-neighbour
    distances [m^2]; with `squared=False` the mean Euclidean distance [m].
    """
    P = as_points(A, "A")
    Q = as_points(B, "B")
    d_ab, _ = cKDTree(Q).query(P, k=1)
    d_ba, _ = cKDTree(P).query(Q, k=1)
    if squared:
        a_to_b, b_to_a = float(np.mean(d_ab**2)), float(np.mean(d_ba**2))
    else:
        a_to_b, b_to_a = float(np.mean(d_ab)), float(np.mean(d_ba))
    return ChamferResult(a_to_b=a_to_b, b_to_a=b_to_a, total=a_to_b + b_to_a)
