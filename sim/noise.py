"""Depth-sensor noise: what a clean rendered depth image goes through to look like a real RGB-D camera's.

The model has the effects a person who has used RealSense or Kinect cameras would name, in this order:

1. edge dropout: pixels next to a depth discontinuity (stereo occlusion shadows, ToF mixed pixels that the
   driver filters) are invalidated with a probability;
2. axial noise: Gaussian along the ray with sigma(z) = a + b z^2 (stereo: the disparity error grows the depth
   error with z^2; ToF: nearly constant, small b);
3. random holes: elliptic blobs with no reading (specular or dark surfaces, IR interference);
4. range limits: readings outside [min_range_m, max_range_m] are invalid;
5. quantisation to the sensor's depth unit (1 mm for uint16 millimetre output).

Invalid pixels are 0 (DESIGN.md: 0 or NaN is "no reading"). A seeded `numpy.random.Generator` is always
passed in; nothing here touches global random state.

Presets (`NOISE_PRESETS`): "clean" (no change at all), "realsense" (Intel RealSense D435-like active stereo at
848x480: sigma about 2.5 mm at 0.5 m and 6 mm at 1 m, minimum range 0.1 m, shadow dropout at edges) and
"kinect" (Azure Kinect NFOV-like time of flight: sigma about 1.7 mm, nearly flat in z, minimum range 0.5 m,
invalidated mixed pixels at edges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from prompose_grasp.errors import InvalidInputError, UnknownNameError

__all__ = ["NOISE_PRESETS", "DepthNoiseConfig", "apply_color_noise", "apply_depth_noise", "noise_preset"]


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Sensor noise settings. All lengths in metres, probabilities in [0, 1].

    Attributes:
        name: preset name, for logs and dataset metadata.
        axial_sigma_a_m: constant term of sigma(z) = a + b z^2 [m].
        axial_sigma_b_per_m: quadratic term b [1/m].
        edge_jump_m: a neighbour depth difference above this marks a discontinuity [m].
        edge_width_px: half-width of the band around a discontinuity where dropout may happen [px].
        edge_dropout_prob: probability that a pixel in that band reads nothing.
        holes_per_megapixel: mean number of hole blobs per 10^6 pixels (Poisson).
        hole_radius_px: (min, max) radius of a blob [px].
        min_range_m, max_range_m: the sensor's working range [m].
        quantisation_m: depth unit [m]; 0 keeps float precision.
        color_sigma: Gaussian noise on colour in 8-bit levels (0 = none).
    """

    name: str = "clean"
    axial_sigma_a_m: float = 0.0
    axial_sigma_b_per_m: float = 0.0
    edge_jump_m: float = 0.02
    edge_width_px: int = 0
    edge_dropout_prob: float = 0.0
    holes_per_megapixel: float = 0.0
    hole_radius_px: tuple[float, float] = (2.0, 6.0)
    min_range_m: float = 0.0
    max_range_m: float = math.inf
    quantisation_m: float = 0.0
    color_sigma: float = 0.0

    def __post_init__(self) -> None:
        for key in (
            "axial_sigma_a_m",
            "axial_sigma_b_per_m",
            "edge_jump_m",
            "holes_per_megapixel",
            "min_range_m",
        ):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidInputError(f"DepthNoiseConfig.{key} must be finite and >= 0, got {value}")
        for key in ("quantisation_m", "color_sigma"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidInputError(f"DepthNoiseConfig.{key} must be finite and >= 0, got {value}")
        if not 0.0 <= self.edge_dropout_prob <= 1.0:
            raise InvalidInputError(f"edge_dropout_prob must lie in [0, 1], got {self.edge_dropout_prob}")
        if self.edge_width_px < 0:
            raise InvalidInputError(f"edge_width_px must be >= 0, got {self.edge_width_px}")
        lo, hi = self.hole_radius_px
        if not (0.0 < lo <= hi and math.isfinite(hi)):
            raise InvalidInputError(
                f"hole_radius_px must be (min, max) with 0 < min <= max, got {self.hole_radius_px}"
            )
        if not self.max_range_m > self.min_range_m:
            raise InvalidInputError(
                f"max_range_m ({self.max_range_m}) must exceed min_range_m ({self.min_range_m})"
            )

    def axial_sigma_m(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """Standard deviation [m] of the axial noise at depth z [m]: a + b z^2."""
        return self.axial_sigma_a_m + self.axial_sigma_b_per_m * np.square(depth_m)

    def error_bound_m(self, depth_m: np.ndarray | float, n_sigma: float = 5.0) -> np.ndarray | float:
        """Bound [m] on |noisy - true| for a surviving pixel at depth z: n_sigma sigma(z) + half a depth unit.

        5 sigma is exceeded by a Gaussian with probability 5.7e-7, so a few hundred thousand pixels rarely
        show one; tests use this as the tolerance "set by the noise model".
        """
        return n_sigma * self.axial_sigma_m(depth_m) + 0.5 * self.quantisation_m


NOISE_PRESETS: dict[str, DepthNoiseConfig] = {
    "clean": DepthNoiseConfig(name="clean"),
    # D435 at 848x480: subpixel RMS ~0.08 px, f ~ 430 px, baseline 50 mm -> sigma_z ~ 0.08 z^2 / (f B)
    # = 0.0037 z^2; plus ~1 mm of texture-dependent floor. Min-Z ~0.1 m; dropout at occlusion shadows.
    "realsense": DepthNoiseConfig(
        name="realsense",
        axial_sigma_a_m=0.001,
        axial_sigma_b_per_m=0.0037,
        edge_jump_m=0.015,
        edge_width_px=2,
        edge_dropout_prob=0.6,
        holes_per_megapixel=15.0,
        hole_radius_px=(2.0, 8.0),
        min_range_m=0.1,
        max_range_m=6.0,
        quantisation_m=0.001,
        color_sigma=2.0,
    ),
    # Azure Kinect NFOV unbinned: random error < 17 mm (std) spec, typically ~1.5-2 mm; range 0.5-3.86 m;
    # mixed (flying) pixels at edges are invalidated by the SDK, so they appear as dropout.
    "kinect": DepthNoiseConfig(
        name="kinect",
        axial_sigma_a_m=0.0015,
        axial_sigma_b_per_m=0.0005,
        edge_jump_m=0.02,
        edge_width_px=1,
        edge_dropout_prob=0.9,
        holes_per_megapixel=6.0,
        hole_radius_px=(2.0, 5.0),
        min_range_m=0.5,
        max_range_m=3.86,
        quantisation_m=0.001,
        color_sigma=1.5,
    ),
}


def noise_preset(name: str) -> DepthNoiseConfig:
    """The named preset; raises `UnknownNameError` listing the presets."""
    try:
        return NOISE_PRESETS[name]
    except KeyError:
        raise UnknownNameError("noise model", name, sorted(NOISE_PRESETS)) from None


def _check_depth(depth_m: np.ndarray) -> np.ndarray:
    d = np.asarray(depth_m)
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.floating):
        raise InvalidInputError(
            f"depth must be a (H, W) float array in metres, got shape {d.shape} dtype {d.dtype}"
        )
    return d


def _discontinuities(depth_m: np.ndarray, valid: np.ndarray, jump_m: float) -> np.ndarray:
    """(H, W) bool: pixels whose 4-neighbourhood holds a depth jump above `jump_m` or an invalid pixel."""
    z = np.where(valid, depth_m, 0.0)
    edge = np.zeros(z.shape, dtype=bool)
    dy = np.abs(np.diff(z, axis=0)) > jump_m
    dx = np.abs(np.diff(z, axis=1)) > jump_m
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    return edge & valid


def apply_depth_noise(depth_m: np.ndarray, config: DepthNoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """Apply the sensor model to a clean depth image.

    Args:
        depth_m: (H, W) float32/float64 depth along the optical axis [m]; 0 or NaN = no reading.
        config: the sensor settings (see `NOISE_PRESETS`).
        rng: seeded generator; the only source of randomness.

    Returns:
        (H, W) float32 depth [m] with 0 where the sensor gives no reading.
    """
    d = _check_depth(depth_m).astype(np.float64)
    valid = np.isfinite(d) & (d > 0.0)
    d = np.where(valid, d, 0.0)
    h, w = d.shape

    if config.edge_width_px > 0 and config.edge_dropout_prob > 0.0:
        edge = _discontinuities(d, valid, config.edge_jump_m)
        band = ndimage.binary_dilation(edge, iterations=config.edge_width_px) & valid
        drop = band & (rng.random((h, w)) < config.edge_dropout_prob)
        valid &= ~drop

    sigma = config.axial_sigma_m(d)
    if config.axial_sigma_a_m > 0.0 or config.axial_sigma_b_per_m > 0.0:
        d = d + rng.standard_normal((h, w)) * sigma

    if config.holes_per_megapixel > 0.0:
        n_holes = rng.poisson(config.holes_per_megapixel * h * w / 1e6)
        if n_holes:
            yy, xx = np.mgrid[0:h, 0:w]
            lo, hi = config.hole_radius_px
            for _ in range(int(n_holes)):
                cy, cx = rng.uniform(0, h), rng.uniform(0, w)
                ry, rx = rng.uniform(lo, hi, size=2)
                # only the blob's bounding window is touched
                y0, y1 = max(int(cy - ry) - 1, 0), min(int(cy + ry) + 2, h)
                x0, x1 = max(int(cx - rx) - 1, 0), min(int(cx + rx) + 2, w)
                win = ((yy[y0:y1, x0:x1] - cy) / ry) ** 2 + ((xx[y0:y1, x0:x1] - cx) / rx) ** 2 <= 1.0
                valid[y0:y1, x0:x1] &= ~win

    valid &= (d >= config.min_range_m) & (d <= config.max_range_m) & (d > 0.0)
    if config.quantisation_m > 0.0:
        d = np.round(d / config.quantisation_m) * config.quantisation_m
    return np.where(valid, d, 0.0).astype(np.float32)


def apply_color_noise(color: np.ndarray, config: DepthNoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 colour with Gaussian read noise of `config.color_sigma` levels, clipped to [0, 255]."""
    c = np.asarray(color)
    if c.ndim != 3 or c.shape[2] != 3 or c.dtype != np.uint8:
        raise InvalidInputError(f"color must be (H, W, 3) uint8, got shape {c.shape} dtype {c.dtype}")
    if config.color_sigma <= 0.0:
        return c.copy()
    noisy = c.astype(np.float32) + rng.standard_normal(c.shape, dtype=np.float32) * np.float32(
        config.color_sigma
    )
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
