"""Superquadrics: the fallback prior for words the library does not know, fitted to the first observation.

A superquadric with half-axes (a_x, a_y, a_z) and shape exponents (e1, e2), with y as its polar axis (the
object's up, as in the canonical frame) has the inside-outside function

    F(x, y, z) = ( |x/a_x|^(2/e2) + |z/a_z|^(2/e2) )^(e2/e1) + |y/a_y|^(2/e1)

F < 1 inside, = 1 on the surface, > 1 outside. e2 shapes the horizontal (x-z) section: 1 an ellipse, towards
0.1 a rectangle; e1 the vertical profile: 1 round, towards 0.1 flat top and bottom. So a can is (e1 ~ 0.1,
e2 = 1), a box (0.1, 0.1), an egg (1, 1).

Fitting (`fit_superquadric`): the observed points (N, 3) are expressed in an object-aligned frame whose y is
the given up direction and whose x is the main horizontal direction of the points (PCA of the points
projected on the horizontal plane); then scipy's least squares adjusts the half-axes, the exponents, the
centre and a yaw about up. The residual of a point p (in the superquadric frame) is its radial distance to the
surface, |p| (1 - F(p)^(-e1/2)) [m] (the surface point on the ray from the centre through p lies at
F(p)^(-e1/2) p, because F(s p) = s^(2/e1) F(p)). F is evaluated in log space so that exponents as small as
0.1 (powers of 20) never overflow.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from prompose_grasp.errors import InvalidInputError

__all__ = [
    "EXPONENT_BOUNDS",
    "SuperquadricFit",
    "fit_superquadric",
    "superquadric_inside_outside",
    "superquadric_mesh",
]

log = logging.getLogger(__name__)

#: Shape exponents are kept in this range. Below 0.1 the powers (2/e > 20) make F so steep that the fit's
#: Jacobian is ill-conditioned while the shape no longer visibly changes (a 0.1 superquadric's diagonal
#: point is within 3.5 % of a box corner, 2^(-0.05) = 0.966); above 1.9 the shape turns into a pinched star
#: that no everyday object has.
EXPONENT_BOUNDS = (0.1, 1.9)

#: Fewer observed points than this cannot constrain 9 parameters robustly.
_MIN_POINTS = 20

#: Added to |coordinate| / a before the logarithm so that points exactly on a symmetry plane (a zero
#: coordinate) give a finite log; 1e-12 of a half-axis is far below any sensor resolution.
_LOG_FLOOR = 1e-12


@dataclass(frozen=True, eq=False)
class SuperquadricFit:
    """A superquadric fitted to points.

    Attributes:
        size_m: (3,) float64 full extents along the superquadric's x, y, z [m] (twice the half-axes);
            x is the longer horizontal axis, y is up.
        e1, e2: shape exponents (vertical profile, horizontal section), within `EXPONENT_BOUNDS`.
        T_frame_sq: (4, 4) float64 pose of the superquadric in the frame of the input points
            (`x_frame = T_frame_sq @ x_sq`); its y axis is the given up direction.
        rms_residual_m: root mean square radial distance of the points to the surface [m].
        n_points: number of points fitted.
    """

    size_m: np.ndarray
    e1: float
    e2: float
    T_frame_sq: np.ndarray
    rms_residual_m: float
    n_points: int


def _log_inside_outside(q: np.ndarray, half: np.ndarray, e1: float, e2: float) -> np.ndarray:
    """log F at (N, 3) points `q` in the superquadric frame (see the module docstring)."""
    lx = np.log(np.abs(q[:, 0]) / half[0] + _LOG_FLOOR)
    ly = np.log(np.abs(q[:, 1]) / half[1] + _LOG_FLOOR)
    lz = np.log(np.abs(q[:, 2]) / half[2] + _LOG_FLOOR)
    horizontal = np.logaddexp((2.0 / e2) * lx, (2.0 / e2) * lz) * (e2 / e1)
    return np.logaddexp(horizontal, (2.0 / e1) * ly)


def superquadric_inside_outside(points: ArrayLike, size_m: ArrayLike, e1: float, e2: float) -> np.ndarray:
    """F at (N, 3) points given in the superquadric's own frame; (N,) float64 (1 on the surface).

    Args:
        points: (N, 3) [m] in the superquadric frame (centre at the origin, y the polar axis).
        size_m: (3,) full extents [m].
        e1, e2: shape exponents (> 0).
    """
    q = _as_points(points, min_points=1)
    half = _as_size(size_m) / 2.0
    _check_exponents(e1, e2, strict=False)
    return np.exp(_log_inside_outside(q, half, float(e1), float(e2)))


def _rot_y(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _residuals(params: np.ndarray, pts: np.ndarray, floor_y: float | None = None) -> np.ndarray:
    half, e1, e2, yaw = params[0:3], params[3], params[4], params[-1]
    if floor_y is None:
        centre = params[5:8]
    else:  # standing on the support: the centre is a half-height above it
        centre = np.array([params[5], floor_y + half[1], params[6]])
    q = (pts - centre) @ _rot_y(yaw)  # rows: R_frame_sq^T (p - c)
    log_f = _log_inside_outside(q, half, e1, e2)
    radius = np.linalg.norm(q, axis=1)
    return radius * (1.0 - np.exp(-0.5 * e1 * log_f))


def _as_points(points: ArrayLike, min_points: int) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidInputError(f"points must be (N, 3) metres, got shape {np.shape(points)}")
    if p.shape[0] < min_points:
        raise InvalidInputError(f"need at least {min_points} points, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise InvalidInputError("points hold NaN or inf; drop invalid depth readings first")
    return p


def _as_size(size_m: ArrayLike) -> np.ndarray:
    s = np.asarray(size_m, dtype=np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InvalidInputError(f"size_m must be (3,) positive finite metres, got {size_m!r}")
    return s


def _check_exponents(e1: float, e2: float, strict: bool = True) -> None:
    lo, hi = EXPONENT_BOUNDS if strict else (1e-3, 10.0)
    for name, e in (("e1", e1), ("e2", e2)):
        if not (isinstance(e, int | float | np.floating) and math.isfinite(e) and lo <= e <= hi):
            raise InvalidInputError(f"{name} must be a finite exponent in [{lo}, {hi}], got {e!r}")


def _object_frame(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) R_frame_obj: columns x (main horizontal direction of the points), y = up, z = x cross y."""
    y = up / np.linalg.norm(up)
    centred = points - points.mean(axis=0)
    horizontal = centred - np.outer(centred @ y, y)
    _, _, vt = np.linalg.svd(horizontal, full_matrices=False)
    # The first right singular vector is horizontal up to rounding; re-orthogonalise against y.
    x = vt[0] - (vt[0] @ y) * y
    if np.linalg.norm(x) < 1e-9:  # all points on the up axis: any horizontal direction will do
        x = np.cross(y, [1.0, 0.0, 0.0] if abs(y[0]) < 0.9 else [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=1)


def fit_superquadric(
    points: ArrayLike, up: ArrayLike = (0.0, -1.0, 0.0), support_offset_m: float | None = None
) -> SuperquadricFit:
    """Fit a superquadric (size, two exponents, centre, yaw about `up`) to observed surface points.

    Args:
        points: (N, 3) float, metres, N >= 20: points on the object's surface (a partial view is fine; the
            unseen side is filled in with the simplest superquadric that agrees with what is seen).
        up: (3,) the object's up direction in the points' frame (any non-zero length). Default (0, -1, 0):
            "up" in an OpenCV camera frame whose camera is level; pass the support plane's normal
            (e.g. `T_cam_support[:3, 2]`) whenever it is known.
        support_offset_m: d of the support plane `n . x + d = 0` whose unit normal n is `up`, when the object
            stands on it: the superquadric's bottom then rests on the plane (its centre a half-height
            above it). A partial view alone leaves the bottom free, and the fit then floats the
            superquadric round the seen surface, often half below the table or as a thin shell.

    Returns:
        `SuperquadricFit`: its frame has y = up and x the longer horizontal axis.
    """
    pts = _as_points(points, min_points=_MIN_POINTS)
    up_v = np.asarray(up, dtype=np.float64)
    if up_v.shape != (3,) or not np.all(np.isfinite(up_v)) or np.linalg.norm(up_v) < 1e-9:
        raise InvalidInputError(f"up must be a finite non-zero (3,) vector, got {up!r}")
    R = _object_frame(pts, up_v)
    local = pts @ R  # points in the object-aligned frame (rows: R^T p)
    lo, hi = local.min(axis=0), local.max(axis=0)
    span = float(np.linalg.norm(hi - lo))
    if span <= 0.0:
        raise InvalidInputError("all points coincide; a superquadric needs a spread of surface points")
    half0 = np.maximum((hi - lo) / 2.0, 0.01 * span)
    centre0 = (lo + hi) / 2.0
    floor_y = None
    if support_offset_m is not None:
        if not math.isfinite(float(support_offset_m)):
            raise InvalidInputError(f"support_offset_m must be finite, got {support_offset_m!r}")
        floor_y = -float(support_offset_m) / float(np.linalg.norm(up_v))
        half0[1] = max(0.5 * (hi[1] - floor_y), 0.01 * span)
        centre0 = np.array([centre0[0], centre0[2]])
    n_centre = len(centre0)
    lower = np.array([1e-4 * span] * 3 + [EXPONENT_BOUNDS[0]] * 2 + [-np.inf] * (n_centre + 1))
    upper = np.array([2.0 * span] * 3 + [EXPONENT_BOUNDS[1]] * 2 + [np.inf] * (n_centre + 1))
    # standing on a plane far below the seen points (a wrist camera's view of a part of a tall object), the
    # half-height reaches down to the plane: it may exceed twice the points' own span
    upper[1] = max(upper[1], 1.5 * half0[1])
    half0 = np.clip(half0, lower[:3], upper[:3])
    best = None
    # Two starts, a rounded and a boxy one: the exponents' cost landscape has a ridge between them.
    for e0 in (0.3, 1.0):
        x0 = np.concatenate([half0, [e0, e0], centre0, [0.0]])
        sol = least_squares(
            _residuals,
            x0,
            bounds=(lower, upper),
            args=(local, floor_y),
            x_scale="jac",
            max_nfev=400,
            method="trf",
        )
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    half, e1, e2, yaw = best.x[0:3], best.x[3], best.x[4], best.x[-1]
    if floor_y is None:
        centre = best.x[5:8]
    else:
        centre = np.array([best.x[5], floor_y + half[1], best.x[6]])
    R_obj_sq = _rot_y(float(yaw))
    if half[2] > half[0]:  # make x the longer horizontal axis: turn the frame 90 degrees about y
        half = half[[2, 1, 0]]
        R_obj_sq = R_obj_sq @ _rot_y(math.pi / 2.0)
    T = np.eye(4)
    T[:3, :3] = R @ R_obj_sq
    T[:3, 3] = R @ centre
    rms = float(np.sqrt(np.mean(best.fun**2)))
    log.debug("superquadric fit: size %s m, e1 %.3f, e2 %.3f, rms %.2e m", 2 * half, e1, e2, rms)
    return SuperquadricFit(
        size_m=2.0 * np.asarray(half, dtype=np.float64),
        e1=float(e1),
        e2=float(e2),
        T_frame_sq=T,
        rms_residual_m=rms,
        n_points=int(pts.shape[0]),
    )


def _signed_power(x: np.ndarray, p: float) -> np.ndarray:
    return np.sign(x) * np.abs(x) ** p


def superquadric_mesh(size_m: ArrayLike, e1: float, e2: float, resolution: int = 48) -> trimesh.Trimesh:
    """A watertight triangle mesh of the superquadric, centred at the origin, y the polar axis [m].

    The surface is parametrised by latitude eta in [-pi/2, pi/2] and longitude omega:
    x = a_x c(eta)^e1 c(omega)^e2, y = a_y s(eta)^e1, z = a_z c(eta)^e1 s(omega)^e2 (signed powers), which
    puts more vertices near the edges of boxy shapes, where the surface bends.

    Args:
        size_m: (3,) full extents [m].
        e1, e2: exponents within `EXPONENT_BOUNDS`.
        resolution: latitude steps from pole to pole (>= 8); longitude gets twice as many.
    """
    half = _as_size(size_m) / 2.0
    _check_exponents(e1, e2)
    if int(resolution) < 8:
        raise InvalidInputError(f"resolution must be >= 8, got {resolution}")
    n_lat, n_lon = int(resolution), 2 * int(resolution)
    eta = np.linspace(-math.pi / 2.0, math.pi / 2.0, n_lat + 1)[1:-1]  # the poles are added separately
    omega = np.linspace(-math.pi, math.pi, n_lon, endpoint=False)
    E, W = np.meshgrid(eta, omega, indexing="ij")
    ce, se = _signed_power(np.cos(E), e1), _signed_power(np.sin(E), e1)
    x = half[0] * ce * _signed_power(np.cos(W), e2)
    y = half[1] * se
    z = half[2] * ce * _signed_power(np.sin(W), e2)
    ring_verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    verts = np.vstack([ring_verts, [[0.0, -half[1], 0.0], [0.0, half[1], 0.0]]])
    south, north = len(ring_verts), len(ring_verts) + 1
    faces = []
    rows = n_lat - 1
    for i in range(rows - 1):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            faces += [[a, c, b], [b, c, d]]
    last = (rows - 1) * n_lon
    for j in range(n_lon):
        faces.append([south, j, (j + 1) % n_lon])
        faces.append([north, last + (j + 1) % n_lon, last + j])
    mesh = trimesh.Trimesh(verts, np.asarray(faces, dtype=np.int64), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh
