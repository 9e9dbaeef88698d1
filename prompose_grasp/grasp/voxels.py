"""Observed points as voxels: the occupied cells of an axis-aligned grid, as cube meshes in blocks.

The collision scene stands for the observed point cloud by its occupied voxels: every voxel a cube, the cubes
of each `VOXEL_BLOCK_M` block one triangle mesh (12 triangles a cube; a cube overlapped by a gripper box is
found because one of its triangles intersects or lies in the box).
"""

from __future__ import annotations

import numpy as np

__all__ = ["VOXEL_BLOCK_M", "voxel_blocks", "voxelize_points"]

#: Edge of the blocks the voxel meshes are split into [m] (about a gripper box: tight block bounds let the
#: broadphase skip most blocks, and few voxels per block reach the exact per-voxel test).
VOXEL_BLOCK_M = 0.10

# Unit cube corners and triangles (outward winding) for voxel meshes.
_CUBE_V = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float64
)
_CUBE_F = np.array(
    [
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ],
    dtype=np.int64,
)  # fmt: skip


def voxelize_points(points: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """(M, 3) centres [m] of the occupied voxels of the grid of edge `voxel_size_m` aligned with the axes."""
    keys = np.unique(np.floor(points / voxel_size_m).astype(np.int64), axis=0)
    return (keys + 0.5) * voxel_size_m


def voxel_blocks(centres: np.ndarray, voxel_size_m: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The voxels of centres (M, 3) [m] grouped by `VOXEL_BLOCK_M` block: per block (its voxel centres (K, 3),
    the cube mesh's vertices (8 K, 3) [m] and triangles (12 K, 3) indices). One mesh per block: tight
    bounding boxes let the broadphase skip the blocks a query is far from (one mesh for all would overlap
    every query's bounding box)."""
    blocks = np.floor(centres / VOXEL_BLOCK_M).astype(np.int64)
    _, block_of = np.unique(blocks, axis=0, return_inverse=True)
    out = []
    for b in range(int(block_of.max()) + 1):
        C = centres[block_of.ravel() == b]
        V = (C[:, None, :] + voxel_size_m * _CUBE_V[None]).reshape(-1, 3)
        F = (np.arange(len(C))[:, None, None] * 8 + _CUBE_F[None]).reshape(-1, 3)
        out.append((C, V, F))
    return out
