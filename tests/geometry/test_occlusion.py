"""Occluder edges and the ends they cut, on constructed inputs."""

from __future__ import annotations

import numpy as np

from prompose_grasp.geometry.occlusion import cut_ends, nearer_beside


def test_a_nearer_surface_within_the_window_marks_the_edge() -> None:
    depth = np.full((20, 40), 1.0)
    depth[:, :10] = 0.5  # nearer, left of the object
    depth[:, 30:] = 2.0  # farther, right of it
    depth[0, 12] = np.nan  # no reading inside the window of (0, 14): never an occluder
    mask = np.zeros((20, 40), dtype=bool)
    mask[:, 10:30] = True
    rows = np.array([5, 5, 5, 0])
    cols = np.array([12, 13, 29, 14])
    # columns 12 and 13 are 3 and 4 px from the nearer surface (column 9); 29 borders the farther one
    out = nearer_beside(depth, mask, rows, cols, depth[rows, cols], radius_px=3, margin_m=0.01)
    assert out.tolist() == [True, False, False, False]
    # nearer by less than the margin: the object's own continuation
    depth[:, :10] = 0.995
    assert not nearer_beside(depth, mask, rows, cols, np.ones(4), radius_px=3, margin_m=0.01).any()


def test_an_end_is_cut_when_half_its_points_lie_on_a_cut_edge() -> None:
    rng = np.random.default_rng(0)
    local = rng.uniform([0.0, 0.0], [0.10, 0.04], (2000, 2))
    lo, hi = np.percentile(local, 2, axis=0), np.percentile(local, 98, axis=0)
    edge = local[:, 0] > 0.099  # the high-x end lies along an occluder's edge (its outer 1 %: half the 2 %)
    assert cut_ends(local, lo, hi, edge, 0.3).tolist() == [[False, True], [False, False]]
    # the same edge is too thin to cut the end at a share of 0.7; no edge cuts nothing
    assert not cut_ends(local, lo, hi, edge, 0.7).any()
    assert not cut_ends(local, lo, hi, np.zeros(len(local), dtype=bool), 0.3).any()
