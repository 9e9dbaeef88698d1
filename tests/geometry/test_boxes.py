"""Boxes: corner order, exact oriented IoU against closed forms and Monte-Carlo, aligned IoU."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import se3
from prompose_grasp.geometry.boxes import (
    BOX_EDGES,
    aligned_box_iou,
    box_corners,
    oriented_box_intersection_volume,
    oriented_box_iou,
)

I3 = np.eye(3)
ZERO = np.zeros(3)
ONE = np.ones(3)
# Closed forms computed in float64 with a few roundings; Qhull's volume is good to ~1e-15 relative.
EXACT_ATOL = 1e-12


def rot_z(deg: float) -> np.ndarray:
    return se3.so3_exp(np.radians(deg) * np.array([0.0, 0.0, 1.0]))


def test_corner_order_is_nocs_order():
    c = box_corners([2.0, 4.0, 6.0])
    assert c.shape == (8, 3)
    assert np.all(c[:4, 1] > 0) and np.all(c[4:, 1] < 0)  # top face (+y) first
    np.testing.assert_array_equal(c[0], [1, 2, 3])
    np.testing.assert_array_equal(c[1], [1, 2, -3])
    np.testing.assert_array_equal(c[2], [-1, 2, 3])
    np.testing.assert_array_equal(c[7], [-1, -2, -3])
    # The 12 edges join corners that differ on exactly one axis, 4 edges per axis with the full side length.
    lengths = np.linalg.norm(c[BOX_EDGES[:, 0]] - c[BOX_EDGES[:, 1]], axis=1)
    assert sorted(lengths.tolist()) == [2.0] * 4 + [4.0] * 4 + [6.0] * 4


def test_identical_disjoint_touching():
    R = se3.random_rotation(np.random.default_rng(0))
    assert oriented_box_iou(R, [1, 2, 3], [0.1, 0.2, 0.3], R, [1, 2, 3], [0.1, 0.2, 0.3]) == pytest.approx(
        1.0, abs=EXACT_ATOL
    )
    assert oriented_box_iou(I3, ZERO, ONE, I3, [5.0, 0, 0], ONE) == 0.0  # far apart
    assert oriented_box_iou(I3, ZERO, ONE, I3, [1.2, 0, 0], ONE) == 0.0  # spheres overlap, boxes do not
    assert oriented_box_iou(I3, ZERO, ONE, I3, [1.0, 0, 0], ONE) == 0.0  # sharing a face
    assert oriented_box_iou(I3, ZERO, ONE, I3, [1.0, 1.0, 0], ONE) == 0.0  # sharing an edge
    assert oriented_box_iou(I3, ZERO, ONE, I3, [1.0, 1.0, 1.0], ONE) == 0.0  # sharing a corner
    # A cube rotated 45 deg about z whose corner just touches the face x = 0.5 of the unit cube.
    assert oriented_box_iou(I3, ZERO, ONE, rot_z(45), [0.5 + np.sqrt(0.5), 0, 0], ONE) == 0.0


def test_half_shifted_aligned_cubes_give_one_third():
    # Overlap is half a cube; union 1.5 cubes.
    assert oriented_box_iou(I3, ZERO, ONE, I3, [0.5, 0, 0], ONE) == pytest.approx(1 / 3, abs=EXACT_ATOL)


def test_cube_vs_cube_rotated_45_about_z():
    # The cross-section is the unit square minus four corner triangles of the 45-deg square: each corner
    # of the rotated square sticks out by h = sqrt(2)/2 - 1/2 and cuts a right isosceles triangle of area
    # h^2, so the regular octagon has area 1 - 4 h^2 = 2 (sqrt 2 - 1); with height 1 that is the
    # intersection volume, and IoU = 2 (sqrt2 - 1) / (2 - 2 (sqrt2 - 1)) = 1 / sqrt 2.
    inter = oriented_box_intersection_volume(I3, ZERO, ONE, rot_z(45), ZERO, ONE)
    assert inter == pytest.approx(2 * (np.sqrt(2) - 1), abs=EXACT_ATOL)
    iou = oriented_box_iou(I3, ZERO, ONE, rot_z(45), ZERO, ONE)
    assert iou == pytest.approx(1 / np.sqrt(2), abs=EXACT_ATOL)


def test_nested_box_and_90_degree_symmetry():
    # A box inside another: intersection is the small box.
    assert oriented_box_iou(I3, ZERO, [2, 2, 2], rot_z(30), ZERO, [0.5, 0.5, 0.5]) == pytest.approx(
        0.125 / 8, abs=EXACT_ATOL
    )
    # Rotating a box by 90 deg about z swaps its x and y extents: the same set of points.
    iou = oriented_box_iou(I3, ZERO, [1, 2, 3], rot_z(90), ZERO, [2, 1, 3])
    assert iou == pytest.approx(1.0, abs=EXACT_ATOL)


def _random_box(rng: np.random.Generator, spread_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return se3.random_rotation(rng), rng.normal(scale=spread_m, size=3), rng.uniform(0.3, 1.5, size=3)


def _perturbed(rng: np.random.Generator, box):
    R, t, s = box
    return (
        R @ se3.so3_exp(rng.normal(scale=0.2, size=3)),
        t + rng.normal(scale=0.1, size=3),
        s * rng.uniform(0.7, 1.3, size=3),
    )


def _monte_carlo_iou(rng, box_a, box_b, n: int) -> float:
    """IoU from the fraction f of n uniform samples of box a that fall in box b: I = f V_a."""
    (R_a, t_a, s_a), (R_b, t_b, s_b) = box_a, box_b
    local_a = rng.uniform(-0.5, 0.5, size=(n, 3)) * s_a
    points = local_a @ R_a.T + t_a
    in_b = np.all(np.abs((points - t_b) @ R_b) <= 0.5 * s_b, axis=1)
    v_a, v_b = np.prod(s_a), np.prod(s_b)
    inter = in_b.mean() * v_a
    return inter / (v_a + v_b - inter)


def test_exact_iou_matches_monte_carlo():
    # With I = f V_a, IoU = I / (V_a + V_b - I) has d IoU / d f = V_a (V_a + V_b) / U^2 <= 2 (as U >= V_a and
    # V_a + V_b <= 2 U), so the MC standard error is <= 2 * 0.5 / sqrt(n) = 1 / sqrt(n) = 0.0016 for n = 400k:
    # the 0.01 bound below is >= 6 standard errors, so a correct exact IoU fails it with probability < 1e-9.
    rng = np.random.default_rng(7)
    n = 400_000
    ious = []
    for i in range(12):
        box_a = _random_box(rng, 0.3)
        # Half the pairs are independent boxes, half perturbed copies (IoU 0.3-0.9, where estimators matter).
        box_b = _random_box(rng, 0.3) if i % 2 else _perturbed(rng, box_a)
        exact = oriented_box_iou(*box_a, *box_b)
        estimate = _monte_carlo_iou(rng, box_a, box_b, n)
        assert abs(exact - estimate) < 0.01
        ious.append(exact)
    assert max(ious) > 0.5 and min(ious) < 0.2  # the sample exercises real, varied overlaps


def test_symmetric_and_invariant_under_common_rigid_transform():
    rng = np.random.default_rng(11)
    for _ in range(30):
        (R_a, t_a, s_a), (R_b, t_b, s_b) = _random_box(rng, 0.4), _random_box(rng, 0.4)
        iou = oriented_box_iou(R_a, t_a, s_a, R_b, t_b, s_b)
        # Swapping the boxes changes which corners/edges are tested first but not the polytope.
        assert oriented_box_iou(R_b, t_b, s_b, R_a, t_a, s_a) == pytest.approx(iou, abs=EXACT_ATOL)
        T = se3.random_transform(rng, translation_scale_m=2.0)
        R, t = T[:3, :3], T[:3, 3]
        moved = oriented_box_iou(R @ R_a, R @ t_a + t, s_a, R @ R_b, R @ t_b + t, s_b)
        assert moved == pytest.approx(iou, abs=1e-9)  # both sides round the moved corners differently


def test_aligned_iou_closed_form_and_agrees_with_oriented():
    assert aligned_box_iou(ZERO, ONE, [0.5, 0, 0], [1.5, 1, 1]) == pytest.approx(1 / 3, abs=EXACT_ATOL)
    assert aligned_box_iou(ZERO, ONE, [1, 0, 0], [2, 1, 1]) == 0.0
    assert aligned_box_iou(ZERO, ONE, ZERO, ONE) == 1.0
    rng = np.random.default_rng(3)
    for _ in range(30):
        lo_a, lo_b = rng.uniform(-1, 0, size=3), rng.uniform(-1, 0, size=3)
        hi_a, hi_b = lo_a + rng.uniform(0.2, 1.5, size=3), lo_b + rng.uniform(0.2, 1.5, size=3)
        expected = oriented_box_iou(I3, (lo_a + hi_a) / 2, hi_a - lo_a, I3, (lo_b + hi_b) / 2, hi_b - lo_b)
        assert aligned_box_iou(lo_a, hi_a, lo_b, hi_b) == pytest.approx(expected, abs=EXACT_ATOL)


def test_validation():
    with pytest.raises(InvalidInputError, match="> 0"):
        oriented_box_iou(I3, ZERO, [1, 0, 1], I3, ZERO, ONE)
    with pytest.raises(InvalidInputError, match="rotation"):
        oriented_box_iou(2 * I3, ZERO, ONE, I3, ZERO, ONE)
    with pytest.raises(InvalidInputError, match="finite"):
        oriented_box_iou(I3, [np.nan, 0, 0], ONE, I3, ZERO, ONE)
    with pytest.raises(InvalidInputError, match="shape"):
        oriented_box_iou(I3, ZERO, ONE, I3, ZERO, [1, 1])
    with pytest.raises(InvalidInputError, match="max > min"):
        aligned_box_iou(ONE, ZERO, ZERO, ONE)
    with pytest.raises(InvalidInputError, match="> 0"):
        box_corners([1, 1, -1])
