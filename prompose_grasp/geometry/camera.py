"""Pinhole camera intrinsics (no distortion) in the OpenCV convention.

Pixel coordinates (u, v): u is the column index (right), v the row index (down), and the centre of pixel
(row i, column j) is at (u, v) = (j, i), i.e. integer coordinates are pixel centres (OpenCV). A camera-frame
point (x, y, z) (x right, y down, z forward, metres) projects to u = fx x / z + cx, v = fy y / z + cy.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError

__all__ = ["CameraIntrinsics"]


def _positive_int(value: object, name: str) -> int:
    if isinstance(value, bool):
        raise InvalidInputError(f"{name} must be a positive integer number of pixels, got {value!r}")
    try:
        n = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        msg = f"{name} must be a positive integer number of pixels, got {value!r}"
        raise InvalidInputError(msg) from None
    if n <= 0:
        raise InvalidInputError(f"{name} must be a positive integer number of pixels, got {n}")
    return int(n)


def _finite(value: object, name: str, positive: bool = False) -> float:
    if isinstance(value, bool | str | bytes):  # float("60") would parse: a number given as text is refused
        raise InvalidInputError(f"{name} must be a finite number of pixels, got {value!r}")
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a finite number of pixels, got {value!r}") from None
    if not math.isfinite(x) or (positive and x <= 0.0):
        need = "finite and > 0" if positive else "finite"
        raise InvalidInputError(f"{name} must be {need} (pixels), got {x}")
    return x


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of an image of `width` x `height` pixels.

    Attributes:
        fx, fy: focal lengths [px], finite and > 0.
        cx, cy: principal point [px], finite (integer coordinates are pixel centres).
        width, height: image size [px], positive integers.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "fx", _finite(self.fx, "fx", positive=True))
        object.__setattr__(self, "fy", _finite(self.fy, "fy", positive=True))
        object.__setattr__(self, "cx", _finite(self.cx, "cx"))
        object.__setattr__(self, "cy", _finite(self.cy, "cy"))
        object.__setattr__(self, "width", _positive_int(self.width, "width"))
        object.__setattr__(self, "height", _positive_int(self.height, "height"))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width): the shape a depth image from this camera has."""
        return (self.height, self.width)

    @classmethod
    def from_K(cls, K: ArrayLike, width: int, height: int) -> CameraIntrinsics:
        """From a (3, 3) matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (zero skew; no distortion)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise InvalidInputError(f"K must be a finite (3, 3) matrix, got shape {K.shape}")
        zeros = K[[0, 1, 2, 2], [1, 0, 0, 1]]
        if np.any(zeros != 0.0) or K[2, 2] != 1.0:
            raise InvalidInputError(
                "K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (zero skew, last row 0 0 1), got "
                f"{np.array2string(K, precision=4, separator=', ')}"
            )
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), width, height)

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
        """Intrinsics of a MuJoCo camera of vertical field of view `fovy_deg` [deg], image width x height.

        MuJoCo's `fovy` spans the full image height (edge to edge), pixels are square and the optical axis
        passes through the centre of the image rectangle. So f = (height / 2) / tan(fovy / 2) for both axes,
        and since integer pixel coordinates here are pixel centres (pixel j covers [j - 0.5, j + 0.5]), the
        image centre is at cx = (width - 1) / 2, cy = (height - 1) / 2 (not width / 2, which is half a pixel
        off).
        MuJoCo's camera frame is OpenGL's (x right, y up, z backward): the sim turns it into this OpenCV frame
        with a 180 deg rotation about x.
        """
        width = _positive_int(width, "width")
        height = _positive_int(height, "height")
        fovy = _finite(fovy_deg, "fovy_deg", positive=True)
        if fovy >= 180.0:
            raise InvalidInputError(f"fovy_deg must be in (0, 180) degrees, got {fovy}")
        f = 0.5 * height / math.tan(math.radians(fovy) / 2.0)
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)

    def project(self, points_cam: ArrayLike) -> np.ndarray:
        """Project (N, 3) camera-frame points [m] to (N, 2) float64 pixel coordinates (u, v).

        Points with z <= 0 (on or behind the camera plane) have no image and get (NaN, NaN). Points outside
        the image rectangle are projected all the same; compare with width and height to clip.
        """
        P = np.asarray(points_cam, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3:
            raise InvalidInputError(f"points_cam must have shape (N, 3), got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise InvalidInputError("points_cam must be finite, got NaN or inf")
        z = P[:, 2]
        uv = np.full((len(P), 2), np.nan)
        front = z > 0.0
        uv[front, 0] = self.fx * P[front, 0] / z[front] + self.cx
        uv[front, 1] = self.fy * P[front, 1] / z[front] + self.cy
        return uv
