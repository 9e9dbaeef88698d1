"""Depth-sensor noise model: presets, statistics of the axial noise, dropout, holes, quantisation."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from sim.noise import NOISE_PRESETS, DepthNoiseConfig, apply_color_noise, apply_depth_noise, noise_preset


def test_presets_and_unknown_name():
    assert {"clean", "realsense", "kinect"} <= set(NOISE_PRESETS)
    with pytest.raises(UnknownNameError, match="realsense"):
        noise_preset("zed")


def test_clean_is_identity(rng):
    depth = rng.uniform(0.3, 2.0, size=(40, 50)).astype(np.float32)
    depth[3, 4] = 0.0
    out = apply_depth_noise(depth, NOISE_PRESETS["clean"], rng)
    np.testing.assert_array_equal(out, depth)


def test_axial_sigma_grows_with_depth_squared(rng):
    cfg = DepthNoiseConfig(name="t", axial_sigma_a_m=0.001, axial_sigma_b_per_m=0.004)
    for z in (0.5, 1.0, 2.0):
        depth = np.full((200, 200), z, dtype=np.float32)
        err = apply_depth_noise(depth, cfg, rng).astype(np.float64) - z
        expected = 0.001 + 0.004 * z**2
        # 40000 samples: the sample std is within 2 % of sigma (its relative sd is 1/sqrt(2N) = 0.35 %)
        assert np.std(err) == pytest.approx(expected, rel=0.02)
        assert abs(np.mean(err)) < 5 * expected / 200  # 5 standard errors of the mean


def test_quantisation_and_range(rng):
    cfg = DepthNoiseConfig(name="q", quantisation_m=0.001, min_range_m=0.4, max_range_m=1.5)
    depth = rng.uniform(0.2, 2.0, size=(64, 64)).astype(np.float32)
    out = apply_depth_noise(depth, cfg, rng).astype(np.float64)
    valid = out > 0
    np.testing.assert_allclose(
        out[valid] * 1000.0, np.round(out[valid] * 1000.0), atol=1e-3
    )  # float32 mm grid
    assert np.all((depth[valid] >= 0.4 - 5e-4) & (depth[valid] <= 1.5 + 5e-4))  # half a unit of rounding
    assert not np.any(valid & ((depth < 0.399) | (depth > 1.501)))


def test_edge_dropout_only_near_discontinuities(rng):
    depth = np.full((60, 80), 1.0, dtype=np.float32)
    depth[:, 40:] = 1.5  # one vertical step edge between columns 39 and 40
    cfg = DepthNoiseConfig(name="e", edge_jump_m=0.02, edge_width_px=2, edge_dropout_prob=1.0)
    out = apply_depth_noise(depth, cfg, rng)
    dropped_cols = np.unique(np.nonzero(out == 0)[1])
    np.testing.assert_array_equal(dropped_cols, np.arange(37, 43))  # the edge pixels dilated by 2


def test_holes_are_blobs_and_seeded(rng):
    cfg = DepthNoiseConfig(name="h", holes_per_megapixel=2000.0, hole_radius_px=(3.0, 5.0))
    depth = np.ones((100, 100), dtype=np.float32)
    a = apply_depth_noise(depth, cfg, np.random.default_rng(7))
    b = apply_depth_noise(depth, cfg, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    frac = np.mean(a == 0)
    assert 0.0 < frac < 0.9


def test_error_bound_and_validation():
    cfg = NOISE_PRESETS["realsense"]
    assert cfg.error_bound_m(1.0) == pytest.approx(5 * (0.001 + 0.0037) + 0.0005)
    with pytest.raises(InvalidInputError):
        DepthNoiseConfig(edge_dropout_prob=1.5)
    with pytest.raises(InvalidInputError):
        apply_depth_noise(np.ones((4, 4, 1), np.float32), cfg, np.random.default_rng(0))


def test_color_noise(rng):
    img = np.full((30, 30, 3), 128, np.uint8)
    out = apply_color_noise(img, NOISE_PRESETS["realsense"], rng)
    assert out.dtype == np.uint8 and 1.0 < out.astype(float).std() < 3.0  # sigma 2 levels
