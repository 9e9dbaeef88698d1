"""The 9-DoF object pose: rotation, translation and anisotropic size of an amodal box in the camera frame.

`Pose9D(R, t, size)`: `R` (3, 3) is `R_cam_obj`, `t` (3,) the box centre in the camera frame [m], `size` (3,)
the full extents along the object axes [m]. The box is amodal (it bounds the whole object, seen or not); the
object frame has its origin at the box centre and +y the object's up. See docs/conventions.md.

NOCS relation: NOCS stores a pose as a similarity `sRT` (4, 4) with `sRT[:3, :3] = s R`, `sRT[:3, 3] = t`, and
per-axis `scales` (3,) of the model normalised so that its bounding-box diagonal is 1. Hence
`s = |size|` (the diagonal) and `scales = size / s`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.boxes import box_corners, oriented_box_iou
from prompose_grasp.geometry.pointcloud import as_points
from prompose_grasp.geometry.se3 import as_rotation, as_transform, make_T, rotation_angle
from prompose_grasp.geometry.tolerances import POSE_ALLCLOSE_M, POSE_ALLCLOSE_RAD, ROTATION_ATOL

__all__ = ["Pose9D", "pose_errors"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Pose9D:
    """A 9-DoF box pose. Fields are read-only float64 arrays.

    Attributes:
        R: (3, 3) float64, `R_cam_obj`, rotation from the object frame to the camera frame.
        t: (3,) float64, box centre in the camera frame [m].
        size: (3,) float64, full box extents along the object's x, y, z axes [m], all > 0.
    """

    R: np.ndarray
    t: np.ndarray
    size: np.ndarray

    def __post_init__(self) -> None:
        R = as_rotation(self.R, "Pose9D.R")
        try:
            t = np.asarray(self.t, dtype=np.float64)
            size = np.asarray(self.size, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInputError(
                f"Pose9D.t and Pose9D.size must be finite (3,) vectors in metres, got {self.t!r:.40}, "
                f"{self.size!r:.40}"
            ) from None
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise InvalidInputError(f"Pose9D.t must be a finite (3,) vector in metres, got {self.t!r}")
        if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size <= 0.0):
            raise InvalidInputError(
                f"Pose9D.size must be a finite (3,) vector of full extents > 0 in metres, got {self.size!r}"
            )
        object.__setattr__(self, "R", _readonly(R))
        object.__setattr__(self, "t", _readonly(t))
        object.__setattr__(self, "size", _readonly(size))

    def __reduce__(self) -> tuple[Any, ...]:
        # Rebuild through __init__ so unpickled arrays are validated and read-only again.
        return (Pose9D, (np.array(self.R), np.array(self.t), np.array(self.size)))

    def __repr__(self) -> str:
        R, t, size = (a.round(6).tolist() for a in (self.R, self.t, self.size))
        return f"Pose9D(R={R}, t={t}, size={size})"

    # ----------------------------------------------------------------------------------------------------
    # Conversions

    def to_matrix(self) -> np.ndarray:
        """(4, 4) float64 `T_cam_obj` (rotation and box centre; the size is not part of it)."""
        return make_T(self.R, self.t)

    @classmethod
    def from_matrix(cls, T_cam_obj: ArrayLike, size: ArrayLike) -> Pose9D:
        """Pose from a rigid transform `T_cam_obj` (4, 4) and full extents `size` (3,) [m]."""
        T = as_transform(T_cam_obj, "T_cam_obj")
        return cls(T[:3, :3], T[:3, 3], np.asarray(size, dtype=np.float64))

    def to_nocs_sRT(self) -> tuple[np.ndarray, np.ndarray]:
        """NOCS form: `sRT` (4, 4) with `sRT[:3, :3] = s R`, `sRT[:3, 3] = t`, `s = |size|` [m], and `scales`
        (3,) = size / s (unit-diagonal box extents)."""
        s = float(np.linalg.norm(self.size))
        sRT = make_T(self.R, self.t)
        sRT[:3, :3] *= s
        return sRT, self.size / s

    @classmethod
    def from_nocs_sRT(cls, sRT: ArrayLike, scales: ArrayLike) -> Pose9D:
        """Inverse of `to_nocs_sRT`: s = cbrt(det sRT[:3, :3]), R = sRT[:3, :3] / s, size = s * scales."""
        M = np.asarray(sRT, dtype=np.float64)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise InvalidInputError(f"sRT must be a finite (4, 4) matrix, got shape {M.shape}")
        if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=ROTATION_ATOL):
            raise InvalidInputError(f"sRT must have last row (0, 0, 0, 1), got {M[3]}")
        det = float(np.linalg.det(M[:3, :3]))
        if det <= 0.0:
            raise InvalidInputError(f"sRT[:3, :3] must be s R with s > 0, R a rotation; its det is {det:.6g}")
        s = float(np.cbrt(det))
        scales = np.asarray(scales, dtype=np.float64)
        if scales.shape != (3,):
            raise InvalidInputError(f"scales must have shape (3,), got {scales.shape}")
        return cls(as_rotation(M[:3, :3] / s, "sRT[:3, :3] / s"), M[:3, 3], s * scales)

    def to_dict(self) -> dict[str, list]:
        """JSON-ready `{"R": 3x3 list, "t": [3], "size": [3]}` (the CLI's object fields)."""
        return {"R": self.R.tolist(), "t": self.t.tolist(), "size": self.size.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Pose9D:
        """Inverse of `to_dict`; extra keys are ignored."""
        try:
            return cls(d["R"], d["t"], d["size"])
        except KeyError as err:
            raise InvalidInputError(f"a Pose9D dict needs keys R, t, size; missing {err}") from None

    # ----------------------------------------------------------------------------------------------------
    # Geometry

    @property
    def volume(self) -> float:
        """Box volume [m^3]."""
        return float(np.prod(self.size))

    def corners(self) -> np.ndarray:
        """(8, 3) float64 box corners in the camera frame [m], in `boxes.box_corners` order (NOCS order:
        corners 0-3 on the object's top face +y, 4-7 on the bottom face)."""
        return box_corners(self.size) @ self.R.T + self.t

    def transformed(self, T_a_cam: ArrayLike) -> Pose9D:
        """The same box expressed in frame a: R_a_obj = R_a_cam R, t_a = T_a_cam t; the size is unchanged."""
        T = as_transform(T_a_cam, "T_a_cam")
        return Pose9D(T[:3, :3] @ self.R, T[:3, :3] @ self.t + T[:3, 3], self.size)

    def points_to_camera(self, points_unit: ArrayLike) -> np.ndarray:
        """Map (N, 3) canonical points of the unit box [-0.5, 0.5]^3 to the camera frame: R diag(size) p + t.

        This is the paper's scaled canonical prior (section 3.7). Returns (N, 3) float64 [m].
        """
        P = as_points(points_unit, "points_unit", min_points=0)
        return (P * self.size) @ self.R.T + self.t

    def points_to_unit(self, points_cam: ArrayLike) -> np.ndarray:
        """Inverse of `points_to_camera`: diag(1/size) R^T (p - t). (N, 3) [m] -> (N, 3) unit-box coords."""
        P = as_points(points_cam, "points_cam", min_points=0)
        return ((P - self.t) @ self.R) / self.size

    def points_to_object(self, points_cam: ArrayLike) -> np.ndarray:
        """(N, 3) camera-frame points [m] -> (N, 3) object-frame points [m]: R^T (p - t)."""
        P = as_points(points_cam, "points_cam", min_points=0)
        return (P - self.t) @ self.R

    def contains(self, points_cam: ArrayLike, margin_m: float = 0.0) -> np.ndarray:
        """(N,) bool: which camera-frame points lie in the box grown by `margin_m` [m] on every side
        (negative shrinks; the box boundary counts as inside)."""
        margin = float(margin_m)
        if not np.isfinite(margin) or margin <= -0.5 * float(self.size.min()):
            raise InvalidInputError(
                f"margin_m must be finite and > -min(size)/2 = {-0.5 * float(self.size.min()):.6g} m, "
                f"got {margin}"
            )
        local = self.points_to_object(points_cam)
        return np.all(np.abs(local) <= 0.5 * self.size + margin, axis=1)

    def iou(self, other: Pose9D) -> float:
        """Exact 3D IoU of the two oriented boxes (no symmetry handling; see prompose_grasp.eval for that)."""
        return oriented_box_iou(self.R, self.t, self.size, other.R, other.t, other.size)

    def allclose(
        self,
        other: Pose9D,
        rotation_atol_rad: float = POSE_ALLCLOSE_RAD,
        translation_atol_m: float = POSE_ALLCLOSE_M,
        size_atol_m: float = POSE_ALLCLOSE_M,
    ) -> bool:
        """True when the geodesic rotation angle, the centre distance and every size difference are within
        the tolerances. Object symmetries are not considered (the poses must match as given)."""
        rot_err, trans_err = pose_errors(self, other)
        return (
            rot_err <= rotation_atol_rad
            and trans_err <= translation_atol_m
            and bool(np.all(np.abs(self.size - other.size) <= size_atol_m))
        )


def pose_errors(a: Pose9D, b: Pose9D) -> tuple[float, float]:
    """(rotation_error_rad, translation_error_m): geodesic angle between a.R and b.R in [0, pi] and the
    Euclidean distance between the box centres. No symmetry handling (the NOCS metrics in
    prompose_grasp.eval treat symmetric categories)."""
    return rotation_angle(a.R, b.R), float(np.linalg.norm(a.t - b.t))
