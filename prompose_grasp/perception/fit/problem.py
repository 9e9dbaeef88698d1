"""The fit's parameters and its fixed data: a hypothesis's state (`_State`), what stays fixed while it is
optimised (`_Problem`), and the reduced parameterisation of a Gauss-Newton step (`_basis`).

A step is a 9-vector of full parameters, named by the slices below; the reduced parameters are those the
constraints leave free (an upright object turns about the up direction only, a box on the support plane
moves along the plane only, a round section has one width), and `_Problem.basis` maps them onto it.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.geometry.pointcloud import farthest_point_sampling
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.fit.observation import SceneView
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.prior import ShapePrior

#: Full parameters of a step: a left rotation increment omega [rad] (R <- exp(omega) R) ...
ROT = slice(0, 3)
#: ... a move of the box's centre, or of its bottom-face centre with a support plane [m] ...
TRANS = slice(3, 6)
#: ... and a change of the log sizes (x, y, z) ...
LOG_SIZE = slice(6, 9)
#: ... of which the height's: with a support plane the centre rises with it (the bottom is held).
LOG_HEIGHT = 7
#: Length of the full parameter vector.
DOF = 9


@dataclass
class _State:
    R: np.ndarray  # (3, 3) R_cam_obj
    b: np.ndarray  # (3,) box centre, or bottom-face centre on the plane in plane mode
    log_s: np.ndarray  # (3,)

    def copy(self) -> _State:
        return _State(self.R.copy(), self.b.copy(), self.log_s.copy())


@dataclass
class _Problem:
    """Everything that stays fixed while one hypothesis is optimised."""

    obs: np.ndarray  # (N, 3) camera frame
    obs_tree: cKDTree
    prior_p: np.ndarray  # (M, 3) unit box
    prior_n: np.ndarray  # (M, 3)
    up: np.ndarray | None
    plane: tuple[np.ndarray, float] | None
    basis: np.ndarray  # (DOF, D): the full step (ROT, TRANS, LOG_SIZE) = basis @ reduced step
    log_aspect: np.ndarray  # (3,) log of the prior's metric aspect
    config: FitConfig
    scene: SceneView | None = None
    iterations: int = field(default=0)
    # the last `_evaluate` ([state, result, terms of its normal equations]): the final scoring of a fit
    # re-evaluates the state the optimiser ended on; and the observation's unit rays, computed once
    memo: list | None = field(default=None, repr=False, compare=False)
    rays: np.ndarray | None = field(default=None, repr=False, compare=False)
    # a body of revolution (y_continuous): the containment term holds the points in its inscribed cylinder
    round_section: bool = False
    # `scene` is used for its image bounds only (coarse stages of an object the image border cuts off)
    scene_image_only: bool = False
    # per extent pair (x:y, y:z, x:z), `config.aspect_weight` times the prior's family's factors
    # (`ShapeFamily.aspect_weight_factors`)
    aspect_factors: np.ndarray = field(default_factory=lambda: np.ones(3))

    def centre(self, st: _State) -> np.ndarray:
        if self.plane is None:
            return st.b
        assert self.up is not None
        return st.b + 0.5 * math.exp(st.log_s[1]) * self.up

    def pose(self, st: _State) -> Pose9D:
        return Pose9D(st.R, self.centre(st), np.exp(st.log_s))


def _plane_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane orthogonal to `up` (e1 the camera x direction projected)."""
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2


def _basis(up: np.ndarray | None, plane: tuple[np.ndarray, float] | None, symmetry: str) -> np.ndarray:
    """(DOF, D) the columns of the reduced parameters in the full ones: rotation about `up` only when it is
    given (else all three), translation along the plane only when one is given (else all three), and one
    section width for a body of revolution, one size for a sphere (else three sizes)."""
    e = np.eye(DOF)
    rot_x, rot_y, rot_z = e[ROT]
    trans_x, trans_y, trans_z = e[TRANS]
    size_x, size_y, size_z = e[LOG_SIZE]
    cols = []
    if up is None:
        cols += [rot_x, rot_y, rot_z]
    else:
        turn = np.zeros(DOF)
        turn[ROT] = up
        cols.append(turn)
    if plane is None:
        cols += [trans_x, trans_y, trans_z]
    else:
        for direction in _plane_basis(plane[0]):
            move = np.zeros(DOF)
            move[TRANS] = direction
            cols.append(move)
    if symmetry == "y_continuous":
        cols += [size_x + size_z, size_y]
    elif symmetry == "spherical":
        cols += [size_x + size_y + size_z]
    else:
        cols += [size_x, size_y, size_z]
    return np.column_stack(cols)


#: Farthest-point order of each prior's points (first 2048), kept while the prior lives.
_PRIOR_ORDER: weakref.WeakKeyDictionary[ShapePrior, np.ndarray] = weakref.WeakKeyDictionary()


def _prior_subset(prior: ShapePrior, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) unit-box points and (n, 3) normals: the first n farthest-point samples of the prior, so that a
    smaller subset is a coarser version of a larger one."""
    order = _PRIOR_ORDER.get(prior)
    if order is None:
        pts = np.asarray(prior.points, dtype=np.float64)
        order = farthest_point_sampling(pts, min(len(pts), 2048))
        _PRIOR_ORDER[prior] = order
    idx = order[: min(n, len(order))]
    return (
        np.asarray(prior.points, dtype=np.float64)[idx],
        np.asarray(prior.normals, dtype=np.float64)[idx],
    )
