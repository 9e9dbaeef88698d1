"""A round body with a protrusion (a mug and its handle, `priors.library.round_body_axis`): the handle's yaw
about the body's axis after the fit.

The body's terms leave the handle's turn about the body loosely held: a seen handle can sit a quarter turn
off, a hidden one anywhere out of sight. The handle's own points set its yaw (`_handle_yaw`); a hidden
handle goes to the middle of the turns that hide it (`_middle_of_flat_band`). `FitConfig`'s `handle_*`
fields (docs/fit.md, "Hidden handle").
"""

from __future__ import annotations

import logging
import math
import weakref

import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import so3_exp
from prompose_grasp.perception.fit.objective import _evaluate
from prompose_grasp.perception.fit.problem import _Problem, _State
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.prior import ShapePrior

__all__ = ["protrusion_points"]

log = logging.getLogger(__name__)


def _turn_about_body(pb: _Problem, st: _State, axis_xz: np.ndarray, angle: float) -> _State:
    """`st` turned by `angle` [rad] about the vertical line through its posed round-body axis (`axis_xz`,
    unit-box x and z): the body stays where it is, the protrusion (a mug's handle) and with it the box
    centre swing round. Upright fits only."""
    assert pb.up is not None
    up = pb.up
    s = np.exp(st.log_s)
    lever = np.array([s[0] * axis_xz[0], s[2] * axis_xz[1]])
    axis_pt = pb.centre(st) + st.R[:, 0] * lever[0] + st.R[:, 2] * lever[1]
    R = so3_exp(up * angle) @ st.R
    centre = axis_pt - R[:, 0] * lever[0] - R[:, 2] * lever[1]
    b = centre - 0.5 * s[1] * up if pb.plane is not None else centre
    return _State(R, b, st.log_s.copy())


def protrusion_points(pose: Pose9D, axis_xz: np.ndarray, pts: np.ndarray, margin: float) -> np.ndarray:
    """The observed points `pts` outside the posed round body by more than `margin` [m]: points only the
    protrusion (a mug's handle) explains (`priors.library.round_body_axis`)."""
    return pts[_body_ellipse((pts - pose.t) @ pose.R, axis_xz, pose.size, margin) > 1.0]


def _body_ellipse(local: np.ndarray, axis_xz: np.ndarray, size: np.ndarray, margin: float) -> np.ndarray:
    """(N,) elliptic radius of object-frame points about the round body's axis: 1 on the body's side wall
    grown by `margin` [m], > 1 outside it (the ellipse reaches the box's -x face and its z faces)."""
    rx = (axis_xz[0] + 0.5) * size[0] + margin
    rz = 0.5 * size[2] + margin
    dx = local[:, 0] - axis_xz[0] * size[0]
    dz = local[:, 2] - axis_xz[1] * size[2]
    return np.sqrt((dx / rx) ** 2 + (dz / rz) ** 2)


#: Prior points of the protrusion (outside the round body by 5 % of its radius), per prior.
_PROTRUSION: weakref.WeakKeyDictionary[ShapePrior, tuple[np.ndarray, np.ndarray]] = (
    weakref.WeakKeyDictionary()
)


def _handle_yaw(
    pb: _Problem,
    st: _State,
    axis_xz: np.ndarray,
    prior: ShapePrior,
    seen: np.ndarray,
    range_deg: float,
    coarse_deg: float = 3.0,
) -> tuple[_State, float]:
    """`st` turned about the round body's axis (within +-`range_deg`, to 1 deg) to the turn whose visible
    protrusion points (the prior's handle, facing the camera) lie closest to the observed protrusion points
    `seen` (mean squared distance, each capped at 1 cm), and that cost [m^2] (inf when no turn shows the
    handle)."""
    cached = _PROTRUSION.get(prior)
    if cached is None:
        P = np.asarray(prior.points, dtype=np.float64)
        unit = np.array([1.0, 1.0, 1.0])
        keep = _body_ellipse(P, axis_xz, unit, 0.0) > 1.05
        cached = (P[keep], np.asarray(prior.normals, dtype=np.float64)[keep])
        _PROTRUSION[prior] = cached
    hp, hn = cached
    if len(hp) < 4:
        return st, math.inf
    s = np.exp(st.log_s)
    tried: dict[float, tuple[float, _State]] = {}

    def cost_at(a: float) -> float:
        if a not in tried:
            cand = st if a == 0.0 else _turn_about_body(pb, st, axis_xz, math.radians(a))
            x = (hp * s) @ cand.R.T + pb.centre(cand)
            facing = np.einsum("ij,ij->i", (hn / s) @ cand.R.T, x) < 0.0
            cost = math.inf
            if np.count_nonzero(facing) >= 4:
                d, _ = cKDTree(x[facing]).query(seen, k=1)
                cost = float(np.mean(np.minimum(d, 0.01) ** 2))
            tried[a] = (cost, cand)
        return tried[a][0]

    # coarse steps over the range, then finer steps round the best (1 deg at the end)
    rng = min(range_deg, 180.0)
    a0 = min([*np.arange(-rng, rng + 0.5, coarse_deg).tolist(), 0.0], key=cost_at)
    a1 = min((a0 + d for d in (-2.0, -1.0, 0.0, 1.0, 2.0)), key=cost_at)
    cost = tried[a1][0]
    return (tried[a1][1] if math.isfinite(cost) else st), cost


def _middle_of_flat_band(pb: _Problem, st: _State, axis_xz: np.ndarray, cfg: FitConfig) -> _State | None:
    """For a round body with a protrusion (a mug): the loss over turns of the protrusion about the body's
    axis, every `handle_scan_step_deg` round the circle; the turns whose loss is within `handle_band_tol`
    of the least form a band around it. A seen handle makes the band narrow (its points must be matched):
    then None (keep the optimum). A hidden one leaves it wide (every turn that keeps the handle out of
    sight explains the points equally): then the state turned to the middle of the band."""
    n = max(3, round(360.0 / cfg.handle_scan_step_deg))
    angles = 2.0 * math.pi * np.arange(n) / n
    costs = np.array([_evaluate(pb, st if k == 0 else _turn_about_body(pb, st, axis_xz, float(a)), False)[0]
                      for k, a in enumerate(angles)])  # fmt: skip
    k0 = int(np.argmin(costs))
    flat = costs <= (1.0 + cfg.handle_band_tol) * costs[k0]
    lo = hi = 0  # steps from k0 to the band's ends, round the circle
    while lo < n - 1 and flat[(k0 - lo - 1) % n]:
        lo += 1
    while hi < n - 1 - lo and flat[(k0 + hi + 1) % n]:
        hi += 1
    log.debug("handle band: %d of %d turns within %.2f of the least", lo + hi + 1, n, cfg.handle_band_tol)
    if lo + hi + 1 < cfg.handle_band_min:
        return None
    middle = angles[k0] + 0.5 * (hi - lo) * (2.0 * math.pi / n)
    return _turn_about_body(pb, st, axis_xz, float(middle))


def _place_handle(
    pb: _Problem, st: _State, axis_xz: np.ndarray, prior: ShapePrior, pts: np.ndarray, cfg: FitConfig
) -> _State:
    """`st` with the protrusion about the round body's axis (`axis_xz`) turned to the yaw its own observed
    points (`pts`, (N, 3)) give, or, hidden, to the middle of the turns that hide it; `st` itself when
    neither applies."""
    seen = protrusion_points(pb.pose(st), axis_xz, pts, cfg.handle_margin_m)
    seen = seen[:: max(1, len(seen) // 256)]  # at most 256 of them
    turned = None
    if len(seen) >= cfg.handle_sliver_points and cfg.handle_yaw_range_deg > 0.0:
        # The handle's own points set its yaw, searched all round the body: the fit's optimum can sit
        # a quarter turn off (the body's terms pull on it through the shared x scale of body and
        # handle). Fewer than `handle_min_points` (a handle seen edge-on, or stray edge points of a
        # hidden one) must match the prior's handle closely. Either way the turn must keep the loss
        # within the band that a hidden handle's turns span.
        wide, match = _handle_yaw(pb, st, axis_xz, prior, seen, 180.0, cfg.handle_match_step_deg)
        sure = len(seen) >= cfg.handle_min_points or match <= cfg.handle_match_m**2
        ratio = _evaluate(pb, wide, False)[0] / _evaluate(pb, st, False)[0] if sure else math.inf
        log.debug("handle from %d points: match %.1f mm, loss ratio %.3f", len(seen),
                  1e3 * math.sqrt(match), ratio)  # fmt: skip
        if ratio <= 1.0 + cfg.handle_band_tol:
            turned = wide
        elif len(seen) >= cfg.handle_min_points:
            turned, _ = _handle_yaw(pb, st, axis_xz, prior, seen, cfg.handle_yaw_range_deg)
    if turned is None and len(seen) < cfg.handle_min_points:
        # a mug whose handle is hidden: the middle of the turns that hide it (FitConfig.handle_band_tol)
        turned = _middle_of_flat_band(pb, st, axis_xz, cfg)
    return st if turned is None else turned
