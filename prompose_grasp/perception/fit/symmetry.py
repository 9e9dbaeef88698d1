"""The symmetry-canonical output pose: equal shapes give equal poses, whatever the yaw the fit ended at."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import project_to_so3
from prompose_grasp.perception.fit.inputs import _check_unit
from prompose_grasp.perception.priors.prior import SYMMETRIES

__all__ = ["canonicalize_symmetry"]


def canonicalize_symmetry(pose: Pose9D, symmetry: str, up_cam: ArrayLike | None = None) -> Pose9D:
    """The representative of `pose` under the shape's symmetry group that this library reports.

    - `y_continuous`: the object's y axis is kept; x and z turn about it so that +z points as nearly as
      possible towards the camera (z is the unit projection of -t on the plane orthogonal to y).
    - `x_continuous`: +x is flipped (end-over-end) to have a non-negative camera-x component, then y and z
      turn about x so that +y points as nearly as possible to the camera's up (-y_cam), or to `up_cam`.
    - `box` / `y_2fold`: among the 180-degree turns of the group (about y only for y_2fold, and for box when
      `up_cam` is given and y is up), the one whose +z faces the camera most, with +y up first for box.
    - `spherical`: R = identity; the size becomes the mean of the three.
    - `none`: unchanged.
    """
    sym = symmetry
    if sym not in SYMMETRIES:
        raise InvalidInputError(f"symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
    R, t, size = pose.R.copy(), pose.t, pose.size.copy()
    to_cam = -t / max(float(np.linalg.norm(t)), 1e-12)
    up = _check_unit(up_cam, "up_cam")
    if sym == "y_continuous":
        y = R[:, 1]
        z = to_cam - (to_cam @ y) * y
        if np.linalg.norm(z) > 1e-6:
            z /= np.linalg.norm(z)
            x = np.cross(y, z)
            R = np.column_stack([x, y, z])
        size[0] = size[2] = 0.5 * (size[0] + size[2])
    elif sym == "x_continuous":
        x = R[:, 0]
        if x[0] < 0.0:
            R = R @ np.diag([-1.0, -1.0, 1.0])  # 180 degrees about z keeps the shape (end-over-end)
            x = R[:, 0]
        ref = up if up is not None else np.array([0.0, -1.0, 0.0])
        y = ref - (ref @ x) * x
        if np.linalg.norm(y) > 1e-6:
            y /= np.linalg.norm(y)
            R = np.column_stack([x, y, np.cross(x, y)])
        size[1] = size[2] = 0.5 * (size[1] + size[2])
    elif sym in ("box", "y_2fold"):
        flips = [np.eye(3), np.diag([-1.0, 1.0, -1.0])]
        if sym == "box":
            flips += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
        ref_up = up if up is not None else np.array([0.0, -1.0, 0.0])

        def score(Rc: np.ndarray) -> tuple[float, float]:
            return (round(float(Rc[:, 1] @ ref_up), 9), float(Rc[:, 2] @ to_cam))

        R = max((R @ F for F in flips), key=score)
    elif sym == "spherical":
        R = np.eye(3)
        size[:] = float(np.mean(size))
    return Pose9D(project_to_so3(R), t, size)
