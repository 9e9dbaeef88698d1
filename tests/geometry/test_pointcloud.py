"""Camera intrinsics, back-projection, farthest point sampling and the robust PCA descriptor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import se3
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import (
    back_project,
    depth_to_point_map,
    farthest_point_sampling,
    outline_corrected_points,
    robust_descriptor,
)

# Pixel/metre conversions are a couple of float64 operations on values of order 1-1000: 1e-9 is headroom.
ATOL = 1e-9

# A tiny camera whose numbers make hand computation easy: 5 x 4 pixels.
CAM = CameraIntrinsics(fx=500.0, fy=400.0, cx=2.0, cy=1.5, width=5, height=4)


# ----------------------------------------------------------------------------------------------------
# Camera


def test_intrinsics_validation():
    for bad in ({"fx": 0.0}, {"fy": -1.0}, {"cx": np.nan}, {"fx": np.inf}, {"width": 0}, {"height": 4.5}):
        kwargs = {"fx": 500.0, "fy": 500.0, "cx": 2.0, "cy": 1.5, "width": 5, "height": 4} | bad
        with pytest.raises(InvalidInputError):
            CameraIntrinsics(**kwargs)
    with pytest.raises(InvalidInputError, match="skew"):
        CameraIntrinsics.from_K([[500, 1, 2], [0, 500, 1.5], [0, 0, 1]], 5, 4)
    with pytest.raises(InvalidInputError, match="fovy_deg"):
        CameraIntrinsics.from_fovy(640, 480, 180.0)


def test_K_round_trip():
    assert CameraIntrinsics.from_K(CAM.K, 5, 4) == CAM
    np.testing.assert_array_equal(CAM.K, [[500, 0, 2], [0, 400, 1.5], [0, 0, 1]])
    assert CAM.shape == (4, 5)


def test_from_fovy_puts_the_field_of_view_at_the_image_edges():
    cam = CameraIntrinsics.from_fovy(640, 480, 45.0)
    assert cam.fx == cam.fy  # square pixels
    half = math.tan(math.radians(22.5))
    # Rays at +-fovy/2 hit the top and bottom image edges, half a pixel outside the outer pixel centres.
    uv = cam.project(np.array([[0.0, -half, 1.0], [0.0, half, 1.0], [0.0, 0.0, 2.0]]))
    np.testing.assert_allclose(uv[:, 1], [-0.5, 479.5, 239.5], atol=ATOL)
    np.testing.assert_allclose(uv[:, 0], 319.5, atol=ATOL)


def test_project_known_point_and_behind_camera():
    uv = CAM.project(np.array([[0.008, -0.0025, 2.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(uv[0], [4.0, 1.0], atol=ATOL)  # 500 * 0.004 + 2, 400 * -0.00125 + 1.5
    assert np.isnan(uv[1:]).all()


# ----------------------------------------------------------------------------------------------------
# Back-projection


def hand_depth() -> np.ndarray:
    depth = np.zeros((4, 5), dtype=np.float32)
    depth[1, 4] = 2.0  # (u, v) = (4, 1): x = (4 - 2) 2 / 500 = 0.008, y = (1 - 1.5) 2 / 400 = -0.0025
    depth[0, 0] = 1.0  # (0, 0): x = -2 / 500 = -0.004, y = -1.5 / 400 = -0.00375
    depth[3, 2] = 0.5  # (2, 3): x = 0, y = 1.5 * 0.5 / 400 = 0.001875
    depth[2, 1] = np.nan
    depth[2, 2] = -1.0
    depth[2, 3] = np.inf
    depth[0, 1] = 1e-4  # below the 1 mm floor: no reading
    return depth


def test_back_project_hand_computed_points():
    points = back_project(hand_depth(), CAM)
    assert points.dtype == np.float64
    # Row-major pixel order: (0, 0), (1, 4), (3, 2).
    expected = [[-0.004, -0.00375, 1.0], [0.008, -0.0025, 2.0], [0.0, 0.001875, 0.5]]
    np.testing.assert_allclose(points, expected, atol=ATOL)


def test_back_project_mask_and_errors():
    mask = np.zeros((4, 5), dtype=bool)
    mask[1, 4] = True
    mask[2, 1] = True  # NaN depth: selected by the mask but still dropped
    np.testing.assert_allclose(back_project(hand_depth(), CAM, mask), [[0.008, -0.0025, 2.0]], atol=ATOL)
    np.testing.assert_allclose(back_project(hand_depth(), CAM, mask.astype(np.uint8)), [[0.008, -0.0025, 2]])
    with pytest.raises(InvalidInputError, match="intrinsics"):
        back_project(np.ones((5, 4)), CAM)
    with pytest.raises(InvalidInputError, match="floating"):
        back_project(np.ones((4, 5), dtype=np.uint16), CAM)
    with pytest.raises(InvalidInputError, match="mask"):
        back_project(np.ones((4, 5)), CAM, np.ones((4, 4), dtype=bool))
    with pytest.raises(InvalidInputError, match="mask"):
        back_project(np.ones((4, 5)), CAM, np.ones((4, 5)))
    assert back_project(np.zeros((4, 5)), CAM).shape == (0, 3)


# A 640 x 480 camera for the outline tests: a plate seen face-on covers whole pixels, so its true extent is
# known by construction.
VGA = CameraIntrinsics(fx=400.0, fy=400.0, cx=319.5, cy=239.5, width=640, height=480)


def _plate_scene(rows: slice, cols: slice, plate_z: float = 0.8, background_z: float = 1.2):
    depth = np.full((480, 640), background_z)
    depth[rows, cols] = plate_z
    mask = np.zeros((480, 640), dtype=bool)
    mask[rows, cols] = True
    return depth, mask


def test_outline_correction_recovers_the_extent_of_a_face_on_plate():
    # A plate covering pixel columns 200..299 spans image x from 199.5 to 299.5 (pixel edges): 100 pixels,
    # 100 * z / f = 0.2 m at z = 0.8. Pixel centres span only 99 pixels; the corrected outline spans 100.
    depth, mask = _plate_scene(slice(100, 150), slice(200, 300))
    raw = back_project(depth, VGA, mask)
    pts = outline_corrected_points(depth, VGA, mask, occlusion_margin_m=0.01)
    assert pts.shape == raw.shape
    np.testing.assert_allclose(np.ptp(raw[:, 0]), 99 * 0.8 / 400.0, atol=ATOL)
    np.testing.assert_allclose(np.ptp(pts[:, 0]), 100 * 0.8 / 400.0, atol=ATOL)
    np.testing.assert_allclose(np.ptp(pts[:, 1]), 50 * 0.8 / 400.0, atol=ATOL)
    np.testing.assert_array_equal(pts[:, 2], raw[:, 2])  # depth is kept
    # only the outline moves, by half a pixel per free side (a corner both ways)
    moved = np.any(pts != raw, axis=1)
    assert moved.sum() == 2 * 100 + 2 * 50 - 4
    corner = np.flatnonzero((raw[:, 0] == raw[:, 0].min()) & (raw[:, 1] == raw[:, 1].min()))
    np.testing.assert_allclose(raw[corner, :2] - pts[corner, :2], [[0.001, 0.001]], atol=ATOL)


def test_outline_correction_leaves_edges_cut_by_the_border_or_an_occluder():
    # Plate in the image's top-right corner: its top and right edges are the image border's.
    depth, mask = _plate_scene(slice(0, 40), slice(600, 640))
    # A nearer occluder (0.1 m in front) just left of its lower half; its upper half's left edge is free.
    depth[20:40, 590:600] = 0.7
    raw = back_project(depth, VGA, mask)
    pts = outline_corrected_points(depth, VGA, mask, occlusion_margin_m=0.01)
    shift = np.round((pts[:, :2] - raw[:, :2]) * 400.0 / 0.8, 6)  # in pixels
    u = np.round(raw[:, 0] * 400.0 / 0.8 + 319.5).astype(int)
    v = np.round(raw[:, 1] * 400.0 / 0.8 + 239.5).astype(int)
    assert np.all(shift[u == 639, 0] == 0.0) and np.all(shift[v == 0, 1] == 0.0)  # border: kept
    left = u == 600
    assert np.all(shift[left & (v < 20), 0] == -0.5)  # free edge beside the far background
    assert np.all(shift[left & (v >= 20), 0] == 0.0)  # beside the occluder: kept
    assert np.all(shift[v == 39, 1] == 0.5)  # bottom edge, background below
    # A neighbour without a reading is no occluder: that edge is the object's own.
    depth[20:40, 590:600] = np.nan
    pts = outline_corrected_points(depth, VGA, mask, occlusion_margin_m=0.01)
    assert np.all(np.round((pts[left, 0] - raw[left, 0]) * 400.0 / 0.8, 6) == -0.5)


def test_outline_correction_input_errors():
    depth, mask = _plate_scene(slice(10, 20), slice(10, 20))
    with pytest.raises(InvalidInputError, match="mask"):
        outline_corrected_points(depth, VGA, mask[:-1], 0.01)
    with pytest.raises(InvalidInputError, match="mask"):
        outline_corrected_points(depth, VGA, mask.astype(float), 0.01)
    with pytest.raises(InvalidInputError, match="occlusion_margin_m"):
        outline_corrected_points(depth, VGA, mask, float("nan"))
    with pytest.raises(InvalidInputError, match="floating"):
        outline_corrected_points(depth.astype(np.uint16), VGA, mask, 0.01)
    assert outline_corrected_points(depth, VGA, np.zeros_like(mask), 0.01).shape == (0, 3)


def test_point_map_matches_back_projection():
    depth = hand_depth()
    pmap = depth_to_point_map(depth, CAM)
    assert pmap.shape == (4, 5, 3)
    valid = ~np.isnan(pmap[..., 2])
    np.testing.assert_array_equal(valid.sum(), 3)
    np.testing.assert_allclose(pmap[valid], back_project(depth, CAM), atol=ATOL)
    assert np.isnan(pmap[~valid]).all()


def test_project_back_project_round_trip():
    rng = np.random.default_rng(0)
    cam = CameraIntrinsics(fx=610.0, fy=605.0, cx=321.3, cy=242.7, width=64, height=48)
    depth = rng.uniform(0.3, 2.0, size=(48, 64))
    depth[rng.random(depth.shape) < 0.2] = 0.0
    points = back_project(depth, cam)
    v, u = np.nonzero(depth > 0)
    np.testing.assert_allclose(cam.project(points), np.stack([u, v], axis=1), atol=ATOL)


# ----------------------------------------------------------------------------------------------------
# Farthest point sampling


def naive_fps(points: np.ndarray, n: int, start: int) -> np.ndarray:
    """Textbook O(N n) float64 reference."""
    chosen = [start]
    nearest = np.full(len(points), np.inf)
    for _ in range(n - 1):
        nearest = np.minimum(nearest, np.sum((points - points[chosen[-1]]) ** 2, axis=1))
        chosen.append(int(np.argmax(nearest)))
    return np.array(chosen)


def test_fps_matches_naive_reference():
    for seed in range(10):
        rng = np.random.default_rng(seed)
        points = rng.normal(size=(300, 3)) * [0.1, 0.05, 0.02] + [0.0, 0.0, 0.8]
        start = int(rng.integers(300))
        expected = naive_fps(points, 60, start)
        np.testing.assert_array_equal(farthest_point_sampling(points, 60, start), expected)


def test_fps_properties_and_covering_radius():
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.2, 0.2, size=(2000, 3))
    idx = farthest_point_sampling(points, 128, start_index=17)
    assert idx.shape == (128,) and idx.dtype == np.intp
    assert idx[0] == 17 and len(np.unique(idx)) == 128
    np.testing.assert_array_equal(idx, farthest_point_sampling(points, 128, start_index=17))  # deterministic
    # Brute force: each pick is a point at the largest distance from the picks before it.
    dist = cdist(points, points[idx])
    for k in range(1, 128):
        covering_radius = dist[:, :k].min(axis=1).max()
        # float32 distances inside FPS: agreement to ~1e-7 relative of |p| ~ 0.3 m; 1e-6 m is headroom.
        assert dist[idx[k], :k].min() == pytest.approx(covering_radius, abs=1e-6)


def test_fps_edge_cases():
    points = np.random.default_rng(2).normal(size=(10, 3))
    np.testing.assert_array_equal(farthest_point_sampling(points, 10), np.arange(10))
    np.testing.assert_array_equal(farthest_point_sampling(points, 50), np.arange(10))
    np.testing.assert_array_equal(farthest_point_sampling(points, 1, start_index=4), [4])
    for bad in ({"n": 0}, {"n": 2.5}, {"n": 3, "start_index": 10}, {"n": 3, "start_index": -1}):
        with pytest.raises(InvalidInputError):
            farthest_point_sampling(points, **bad)
    with pytest.raises(InvalidInputError, match="finite"):
        farthest_point_sampling(np.full((4, 3), np.nan), 2)
    with pytest.raises(InvalidInputError, match="empty"):
        farthest_point_sampling(np.zeros((0, 3)), 2)


# ----------------------------------------------------------------------------------------------------
# Robust descriptor


def box_surface_cloud(rng: np.random.Generator, n: int, R: np.ndarray, t: np.ndarray, size: np.ndarray):
    """Points on the surface of a box (uniform per face pair, good enough for a PCA shape)."""
    local = rng.uniform(-0.5, 0.5, size=(n, 3))
    axis = rng.integers(3, size=n)
    local[np.arange(n), axis] = rng.choice([-0.5, 0.5], size=n)
    return (local * size) @ R.T + t


def test_descriptor_matches_independent_computation():
    rng = np.random.default_rng(3)
    R = se3.random_rotation(rng)
    points = box_surface_cloud(rng, 4000, R, np.array([0.05, -0.02, 0.7]), np.array([0.3, 0.12, 0.06]))
    d = robust_descriptor(points)
    lo, hi = np.percentile(points[:, 2], [5, 95])
    kept = points[(points[:, 2] >= lo) & (points[:, 2] <= hi)]
    assert d.num_points == len(kept)
    np.testing.assert_allclose(d.depth_range, [lo, hi])
    np.testing.assert_allclose(d.centroid, kept.mean(axis=0), atol=ATOL)
    np.testing.assert_allclose(d.extents, np.ptp(kept, axis=0), atol=ATOL)
    # PCA by SVD of the centred points (another algorithm than eigh of the covariance).
    _, s, Vt = np.linalg.svd(kept - kept.mean(axis=0), full_matrices=False)
    np.testing.assert_allclose(d.variances, s**2 / len(kept), atol=ATOL)
    np.testing.assert_allclose(np.abs(np.sum(d.axes * Vt.T, axis=0)), 1.0, atol=1e-9)  # same axes up to sign
    np.testing.assert_allclose(d.axes.T @ d.axes, np.eye(3), atol=ATOL)
    assert np.linalg.det(d.axes) == pytest.approx(1.0, abs=ATOL)
    for col in (0, 1):  # the documented sign convention
        assert d.axes[np.argmax(np.abs(d.axes[:, col])), col] > 0
    # The long box side (0.3 m, object x) is the first principal direction.
    assert abs(d.axes[:, 0] @ R[:, 0]) > 0.99
    np.testing.assert_array_equal(d.vector, np.concatenate([d.centroid, d.axes.T.ravel(), d.extents]))
    assert d.vector.shape == (15,)


def test_descriptor_suppresses_depth_outliers():
    rng = np.random.default_rng(4)
    R = se3.random_rotation(rng)
    clean = box_surface_cloud(rng, 5000, R, np.array([0.0, 0.0, 0.8]), np.array([0.2, 0.1, 0.1]))
    # 3 % flying pixels far behind the object (depth edges, background bleeding into the mask).
    outliers = clean[:150] + np.array([0.0, 0.0, 1.5])
    noisy = np.concatenate([clean, outliers])
    d_clean, d_noisy = robust_descriptor(clean), robust_descriptor(noisy)
    # Clipping at p95 removes all outliers plus ~2 % of the object's far side, which moves the centroid by
    # a few mm at most; without clipping the mean would move by 3 % of 1.5 m = 45 mm.
    assert np.linalg.norm(d_noisy.centroid - d_clean.centroid) < 0.005
    assert np.linalg.norm(noisy.mean(axis=0) - clean.mean(axis=0)) > 0.04
    assert np.all(np.abs(d_noisy.extents - d_clean.extents) < 0.02)  # vs > 1.5 m if the outliers counted
    assert abs(d_noisy.axes[:, 0] @ d_clean.axes[:, 0]) > 0.99


def test_descriptor_validation():
    with pytest.raises(InvalidInputError, match="percentiles"):
        robust_descriptor(np.zeros((5, 3)), 95.0, 5.0)
    with pytest.raises(InvalidInputError, match="empty"):
        robust_descriptor(np.zeros((0, 3)))
    d = robust_descriptor(np.array([[0.0, 0.0, 1.0]]))  # a single point: zero spread, still a rotation
    np.testing.assert_allclose(d.extents, 0.0)
    assert np.linalg.det(d.axes) == pytest.approx(1.0, abs=ATOL)


def test_depth_units_are_judged_on_the_median():
    from prompose_grasp.geometry.pointcloud import check_depth_units

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 1.5, (48, 64)).astype(np.float32)
    check_depth_units(depth)  # a table 0.5-1.5 m away
    noisy = depth.copy()
    noisy[:3, :3] = [[-0.2, np.nan, np.inf], [0.0, 60.0, -np.inf], [1e-4, 0.0, 0.0]]
    check_depth_units(noisy)  # single readings out of range are "no reading", not a unit mistake
    check_depth_units(np.zeros((48, 64), np.float32))  # no reading at all: the caller's call
    with pytest.raises(
        InvalidInputError, match=r"looks like millimetres: median \d+; pass metres \(depth_mm / 1000"
    ):
        check_depth_units(depth * 1000)
    with pytest.raises(InvalidInputError, match="mostly negative"):
        check_depth_units(-depth)
    with pytest.raises(InvalidInputError, match=r"lies outside the 0\.05 - 10 m"):
        check_depth_units(depth * 1e6)
    with pytest.raises(InvalidInputError, match=r"lies outside the 0\.05 - 10 m"):
        check_depth_units(depth * 0.01)  # 5-15 mm: nearer than any RGB-D camera measures
