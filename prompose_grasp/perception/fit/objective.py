"""The visibility-aware, robust L_geo of one hypothesis, and its Gauss-Newton normal equations.

Two Chamfer terms with Huber weights: every observed point to its nearest prior point (observation ->
prior), and each prior point the camera could see to its nearest observed point (prior -> observation:
facing the camera, not behind the prior's own nearer surface, and with a `SceneView` not outside the image
or behind an occluder). Plus a weak prior on the log-aspect ratios (sizes the observation leaves free keep
the prior's proportions) and the containment term (the seen points lie inside the amodal box). The normal
equations are summed in closed form from 3x3 moments, in the full parameters (`problem.ROT`, `TRANS`,
`LOG_SIZE`) and then mapped to the reduced ones by `_Problem.basis`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.geometry.se3 import hat
from prompose_grasp.perception.fit.observation import _observable, _pixels
from prompose_grasp.perception.fit.problem import DOF, LOG_HEIGHT, LOG_SIZE, ROT, TRANS, _Problem, _State


class _Value(NamedTuple):
    """The objective at a state: robust cost [m^2], the plain mean squared distances of the two Chamfer
    terms [m^2], and the Gauss-Newton normal equations in the reduced parameters (None unless asked)."""

    cost: float
    obs_to_prior: float
    prior_to_obs: float
    H: np.ndarray | None
    g: np.ndarray | None


def _huber_weights(d: np.ndarray, delta: float) -> np.ndarray:
    w = np.ones_like(d)
    far = d > delta
    w[far] = delta / d[far]
    return w


def _huber_cost(d: np.ndarray, delta: float) -> np.ndarray:
    """Huber cost in squared-distance units: d^2 near, 2 delta d - delta^2 beyond delta."""
    return np.where(d <= delta, d * d, 2.0 * delta * d - delta * delta)


def _not_self_occluded(x: np.ndarray, size: np.ndarray, cos_view: np.ndarray) -> np.ndarray:
    """(M,) bool: posed prior points `x` (M, 3) not hidden behind the prior's own nearer surface.

    A coarse z-buffer of the posed points: image-plane bins of about two point spacings (the spacing from
    the box's surface area over M), and a point is hidden when the nearest point of its bin is in front of
    it by more than its own surface's depth change across a bin (bin width x tan of its viewing angle) plus
    5 mm. Without it a laptop seen from behind its screen lets the hidden keyboard pull onto the screen
    and the box collapses to the screen's thickness.
    """
    area = 2.0 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2])
    bin_m = 2.0 * math.sqrt(area / len(x))
    z = x[:, 2]
    h = len(z) // 2  # the median as np.median computes it (a partition, the mean of the middle pair)
    if len(z) % 2:
        z_ref = float(np.partition(z, h)[h])
    else:
        zp = np.partition(z, (h - 1, h))
        z_ref = float((zp[h - 1] + zp[h]) / 2.0)
    if z_ref <= 0.0:
        return np.ones(len(x), dtype=bool)
    b = bin_m / z_ref
    with np.errstate(divide="ignore", invalid="ignore"):
        iu = np.floor(x[:, 0] / (z * b))
        iv = np.floor(x[:, 1] / (z * b))
    ok = np.isfinite(iu) & np.isfinite(iv) & (z > 0.0)
    if not np.all(ok):
        return np.ones(len(x), dtype=bool)
    iu -= iu.min()
    iv -= iv.min()
    key = (iu * (iv.max() + 1.0) + iv).astype(np.int64)
    z_min = np.full(int(key.max()) + 1, np.inf)
    np.minimum.at(z_min, key, z)
    c = np.clip(cos_view, 1e-3, 1.0)
    tol = 0.005 + bin_m * np.sqrt(1.0 - c * c) / c
    return z <= z_min[key] + tol


def _evaluate(pb: _Problem, st: _State, want_jacobian: bool) -> _Value:
    """Robust objective at `st` and, if asked, its Gauss-Newton normal equations in the reduced params.

    The last evaluation is remembered (`_Problem.memo`, by the state's identity: states are never changed in
    place), with its nearest neighbours: asking again for the same state returns it, and asking for the
    normal equations of a state whose cost alone was asked for (`_optimise`'s accepted trial step) builds
    them on its correspondences, without another pair of nearest-neighbour queries.
    """
    memo = pb.memo
    if memo is None or memo[0] is not st:
        memo = pb.memo = [st, *_objective(pb, st)]
    value: _Value = memo[1]
    if want_jacobian and value.H is None:
        H, g = _jacobian(pb, st, memo[2])
        value = memo[1] = value._replace(H=H, g=g)
    return value


def _objective(pb: _Problem, st: _State) -> tuple[_Value, tuple]:
    """The objective at `st` (without its normal equations), and the terms its normal equations need."""
    s = np.exp(st.log_s)
    t = pb.centre(st)
    RT = st.R.T
    q = (pb.prior_p * s) @ RT  # (M, 3) R diag(s) p
    x = q + t
    n_cam = (pb.prior_n / s) @ RT
    # facing the camera: cos(normal, -x) > visible_cos, i.e. -n.x > visible_cos |n| |x|
    facing = -np.einsum("ij,ij->i", n_cam, x)
    # |n| |x| as np.linalg.norm computes each (sqrt of the sum of squares), without its overheads
    cos_view = facing / (
        np.sqrt(np.add.reduce(n_cam * n_cam, axis=1)) * np.sqrt(np.add.reduce(x * x, axis=1))
    )
    visible = cos_view > pb.config.visible_cos
    if pb.config.self_occlusion:
        visible &= _not_self_occluded(x, s, cos_view)
    if pb.scene is not None:
        idx = np.flatnonzero(visible)  # only the points still in: the projection costs per point
        if pb.scene_image_only:
            visible[idx] = _pixels(pb.scene.intrinsics, x[idx])[0]
        else:
            visible[idx] = _observable(pb.scene, x[idx], pb.config.occlusion_margin_m)
    delta = pb.config.huber_m

    # observation -> prior: every prior point may be the nearest one (see module docstring);
    # prior -> observation: visible prior points only
    vis_idx = np.flatnonzero(visible)
    if len(vis_idx) == 0:  # a degenerate pose; keep the term defined with all points
        vis_idx = np.arange(len(x))
    # unbalanced, non-compact, 32-point leaves: cheapest to build and query for the few hundred points of a
    # warm fit or a coarse stage (the nearest neighbours are exact whatever the tree's layout)
    d_op, j_op = cKDTree(x, leafsize=32, balanced_tree=False, compact_nodes=False).query(pb.obs, k=1)
    d_po, j_po = pb.obs_tree.query(x[vis_idx], k=1)
    op, po = float(np.mean(d_op * d_op)), float(np.mean(d_po * d_po))
    cost = float(_huber_cost(d_op, delta).mean() + _huber_cost(d_po, delta).mean())
    aspect_r = _aspect_residuals(pb, st.log_s)
    cost += float(aspect_r @ aspect_r)
    contain_cost, contain_part = _containment_cost(pb, st, s, t)
    cost += contain_cost
    return _Value(cost, op, po, None, None), (
        s,
        q,
        x,
        d_op,
        j_op,
        d_po,
        j_po,
        vis_idx,
        aspect_r,
        contain_part,
    )


def _jacobian(pb: _Problem, st: _State, terms: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton normal equations (H, g) in the reduced params at `st`, on the correspondences and
    residuals `_objective` found there."""
    s, q, x, d_op, j_op, d_po, j_po, vis_idx, aspect_r, contain_part = terms
    delta = pb.config.huber_m
    n_obs, n_vis = len(pb.obs), len(vis_idx)
    # Residuals r = x_k - y_j, weights w / n so that sum w r^2 is the objective.
    k_all = np.concatenate([j_op, vis_idx])
    y_all = np.concatenate([pb.obs, pb.obs[j_po]])
    w_all = np.concatenate([_huber_weights(d_op, delta) / n_obs, _huber_weights(d_po, delta) / n_vis])
    r = x[k_all] - y_all  # (K, 3)
    qk = q[k_all]
    ak = pb.prior_p[k_all] * s  # (K, 3) s * p: dx/dlog s_i = R[:, i] a_i
    u = 0.5 * s[1] * pb.up if pb.plane is not None else None  # bottom held on the plane: + u on log s_y
    H9, g9 = _normal_equations(qk, ak, r, w_all, st.R, u)
    H = pb.basis.T @ H9 @ pb.basis
    g = pb.basis.T @ g9
    # aspect prior: residuals linear in log s
    Ja = _aspect_jacobian(pb) @ pb.basis[LOG_SIZE]
    H += Ja.T @ Ja
    g += Ja.T @ aspect_r
    if contain_part is not None:
        Jc, wc, ec = _containment_jacobian(pb, st, s, contain_part)
        Jc = Jc @ pb.basis
        H += Jc.T @ (Jc * wc[:, None])
        g += Jc.T @ (wc * ec)
    return H, g


def _containment_cost(pb: _Problem, st: _State, s: np.ndarray, t: np.ndarray) -> tuple[float, tuple | None]:
    """Containment term's cost, and what its Jacobian needs (`_containment_jacobian`; None when no point
    pulls).

    Residual per observed point y and box axis i: e = |l_i| - s_i / 2 - margin when positive, with
    l = R^T (y - t) the point in box axes; Huber-weighted, averaged over the observed points, times
    `contain_weight`. A body of revolution (`_Problem.round_section`) holds its points in the cylinder
    inscribed in the box instead: its x and z residuals become one radial one, e = |(l_x, l_z)| - s_x / 2
    - margin (s_x = s_z for it). Parameters as in `_normal_equations` (left rotation increment, centre or
    bottom, log size); with a plane, the centre moves with log s_y (bottom held).
    """
    lam = pb.config.contain_weight
    if lam <= 0.0:
        return 0.0, None
    d = pb.obs - t
    loc = d @ st.R
    # depth noise moves a point along its ray: along a direction u (box axes) it adds |R u . ray| of it
    if pb.rays is None:  # the observation's unit rays, once per problem
        pb.rays = pb.obs / np.linalg.norm(pb.obs, axis=1, keepdims=True)
    ray_loc = pb.rays @ st.R
    if pb.round_section:
        rho = np.hypot(loc[:, 0], loc[:, 2])
        radial = np.zeros_like(loc)  # (N, 3) the unit radial direction of each point, box axes
        on_axis = rho < 1e-9  # a point on the axis: any radial direction, +x
        safe = np.where(on_axis, 1.0, rho)
        radial[:, 0] = np.where(on_axis, 1.0, loc[:, 0] / safe)
        radial[:, 2] = np.where(on_axis, 0.0, loc[:, 2] / safe)
        extent = np.column_stack([rho, np.abs(loc[:, 1])])
        half = np.array([0.25 * (s[0] + s[2]), 0.5 * s[1]])
        along = np.column_stack([np.einsum("ij,ij->i", ray_loc, radial), ray_loc[:, 1]])
    else:
        radial = None
        extent, half, along = np.abs(loc), 0.5 * s, ray_loc
    margin = pb.config.contain_margin_m + pb.config.contain_ray_margin_m * np.abs(along)
    exc = extent - half - margin
    cap = pb.config.contain_cap_m
    n = len(pb.obs)
    delta = pb.config.huber_m
    # outliers beyond the cap cost a constant (the cap's cost, `_huber_cost` in scalars) and do not pull
    n_out = int(np.count_nonzero(exc > cap))
    k_pt, k_ax = np.nonzero((exc > 0.0) & (exc <= cap))
    cost_out = lam * n_out * (cap * cap if cap <= delta else 2.0 * delta * cap - delta * delta) / n
    if len(k_pt) == 0:
        return cost_out, None
    e = exc[k_pt, k_ax]
    # each residual's outward direction (box axes) and d e / d log s
    out_loc = np.zeros((len(e), 3))
    ds = np.zeros((len(e), 3))
    if radial is not None:
        side = k_ax == 0
        out_loc[side] = radial[k_pt[side]]
        ds[side, 0], ds[side, 2] = -0.25 * s[0], -0.25 * s[2]
        top = ~side
        out_loc[top, 1] = np.sign(loc[k_pt[top], 1])
        ds[top, 1] = -0.5 * s[1]
    else:
        out_loc[np.arange(len(e)), k_ax] = np.sign(loc[k_pt, k_ax])
        ds[np.arange(len(e)), k_ax] = -0.5 * s[k_ax]
    return cost_out + lam * float(_huber_cost(e, delta).sum()) / n, (d[k_pt], out_loc @ st.R.T, ds, e)


def _containment_jacobian(pb: _Problem, st: _State, s: np.ndarray, part: tuple):
    """The containment term's (J (K, DOF), weights (K,), residuals (K,)) from `_containment_cost`'s terms."""
    d, out, ds, e = part  # per residual: the point minus the centre, its outward unit direction (camera)
    J = np.zeros((len(e), DOF))
    J[:, ROT] = _cross_rows(out, d)  # d (out . R^T d) / d omega = out x d
    J[:, TRANS] = -out
    J[:, LOG_SIZE] = ds
    if pb.plane is not None:
        assert pb.up is not None
        J[:, LOG_HEIGHT] += -(out @ pb.up) * 0.5 * s[1]  # the centre rises with the height (bottom held)
    w = pb.config.contain_weight * _huber_weights(e, pb.config.huber_m) / len(pb.obs)
    return J, w, e


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (K, 3) arrays (np.cross spends more time on axis handling than on maths)."""
    return np.column_stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ]
    )


def _normal_equations(
    q: np.ndarray, a: np.ndarray, r: np.ndarray, w: np.ndarray, R: np.ndarray, u: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton H = sum w J^T J (DOF, DOF) and g = sum w J^T r (DOF,) from weighted moments, in closed
    form.

    Per residual r_k = x_k - y_k with x_k = R diag(s) p_k + t and parameters (left rotation increment,
    translation, log size), J_k = [-hat(q_k), I, R diag(a_k)] with q_k = R a_k, a_k = s * p_k, plus the
    constant column u on log s_y when the bottom face is held on the plane. Sums of 3x3 moments replace the
    (3K, DOF) Jacobian, which costs K times more memory traffic.
    """
    W = float(w.sum())
    wq = q * w[:, None]
    wa = a * w[:, None]
    sum_q, sum_a, sum_r = wq.sum(axis=0), wa.sum(axis=0), w @ r
    Q = q.T @ wq  # sum w q q^T
    P = wq.T @ a  # sum w q a^T
    H = np.zeros((DOF, DOF))
    H[ROT, ROT] = np.trace(Q) * np.eye(3) - Q  # sum w hat(q)^T hat(q)
    H[ROT, TRANS] = hat(sum_q)  # sum w (-hat(q))^T I
    H[ROT, LOG_SIZE] = _cross_rows(P.T, R.T).T  # column i: (sum w a_i q) x R[:, i]
    H[TRANS, TRANS] = W * np.eye(3)
    H[TRANS, LOG_SIZE] = R * sum_a  # sum w R diag(a)
    H[LOG_SIZE, LOG_SIZE] = np.diag(np.einsum("ij,ij->j", wa, a))  # sum w diag(a)^2
    H[TRANS, ROT] = H[ROT, TRANS].T
    H[LOG_SIZE, ROT] = H[ROT, LOG_SIZE].T
    H[LOG_SIZE, TRANS] = H[TRANS, LOG_SIZE].T
    g = np.empty(DOF)
    g[ROT] = _cross_rows(wq, r).sum(axis=0)  # sum w hat(q) r
    g[TRANS] = sum_r
    g[LOG_SIZE] = np.einsum("ij,ij->j", wa, r @ R)  # sum w a * (R^T r)
    if u is not None:
        v = np.empty(DOF)  # sum w J0^T u
        v[ROT] = hat(sum_q) @ u
        v[TRANS] = W * u
        v[LOG_SIZE] = sum_a * (R.T @ u)
        H[LOG_HEIGHT, :] += v
        H[:, LOG_HEIGHT] += v
        H[LOG_HEIGHT, LOG_HEIGHT] += W * float(u @ u)
        g[LOG_HEIGHT] += float(u @ sum_r)
    return H, g


_PAIRS = np.array([[0, 1], [1, 2], [0, 2]])


def _aspect_residuals(pb: _Problem, log_s: np.ndarray) -> np.ndarray:
    w = pb.config.aspect_weight * pb.aspect_factors
    diff = log_s[_PAIRS[:, 0]] - log_s[_PAIRS[:, 1]]
    target = pb.log_aspect[_PAIRS[:, 0]] - pb.log_aspect[_PAIRS[:, 1]]
    return w * (diff - target)


def _aspect_jacobian(pb: _Problem) -> np.ndarray:
    J = np.zeros((3, 3))
    J[np.arange(3), _PAIRS[:, 0]] = 1.0
    J[np.arange(3), _PAIRS[:, 1]] = -1.0
    return pb.config.aspect_weight * pb.aspect_factors[:, None] * J
