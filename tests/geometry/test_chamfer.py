"""Chamfer distance against a brute-force computation and known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.chamfer import chamfer_distance, nearest_neighbor_distances

# KD-tree and dense distances agree to float64 rounding of values ~1: 1e-12 is headroom.
ATOL = 1e-12


def test_matches_brute_force():
    rng = np.random.default_rng(0)
    for n, m in ((1, 1), (50, 80), (300, 200)):
        A, B = rng.normal(size=(n, 3)), rng.normal(size=(m, 3)) + 0.3
        D = cdist(A, B)
        result = chamfer_distance(A, B)
        assert result.a_to_b == pytest.approx(np.mean(D.min(axis=1) ** 2), abs=ATOL)
        assert result.b_to_a == pytest.approx(np.mean(D.min(axis=0) ** 2), abs=ATOL)
        assert result.total == pytest.approx(result.a_to_b + result.b_to_a, abs=ATOL)
        plain = chamfer_distance(A, B, squared=False)
        assert plain.a_to_b == pytest.approx(np.mean(D.min(axis=1)), abs=ATOL)
        assert plain.b_to_a == pytest.approx(np.mean(D.min(axis=0)), abs=ATOL)
        dist, idx = nearest_neighbor_distances(A, B)
        np.testing.assert_allclose(dist, D.min(axis=1), atol=ATOL)
        np.testing.assert_array_equal(idx, D.argmin(axis=1))


def test_known_answers():
    A = np.random.default_rng(1).normal(size=(100, 3))
    assert chamfer_distance(A, A).total == 0.0
    shifted = chamfer_distance(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.3]]))
    assert shifted.a_to_b == pytest.approx(0.01, abs=ATOL)  # nearest is 0.1 m away
    assert shifted.b_to_a == pytest.approx((0.01 + 0.09) / 2, abs=ATOL)  # both map to the origin
    # Symmetric in its arguments, with the directions swapped.
    B = A[:40] + 0.05
    ab, ba = chamfer_distance(A, B), chamfer_distance(B, A)
    assert (ab.a_to_b, ab.b_to_a) == pytest.approx((ba.b_to_a, ba.a_to_b), abs=ATOL)


def test_validation():
    with pytest.raises(InvalidInputError, match="empty"):
        chamfer_distance(np.zeros((0, 3)), np.zeros((2, 3)))
    with pytest.raises(InvalidInputError, match="shape"):
        chamfer_distance(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(InvalidInputError, match="finite"):
        chamfer_distance(np.full((2, 3), np.inf), np.zeros((2, 3)))
