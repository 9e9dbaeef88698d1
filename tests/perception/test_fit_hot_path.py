"""The warm fit's hot path (`fit/objective.py`: `_evaluate`; `fit/solver.py`: `_optimise`, `_apply`) gives
what the plain computation gives: the Rodrigues step against `so3_exp`, the remembered last evaluation against
a fresh one, and a whole warm fit against one with both shortcuts undone."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

import prompose_grasp.perception.fit.core as core
import prompose_grasp.perception.fit.handle as handle
import prompose_grasp.perception.fit.objective as objective
import prompose_grasp.perception.fit.observation as observation
import prompose_grasp.perception.fit.problem as problem
import prompose_grasp.perception.fit.solver as solver
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import so3_exp
from prompose_grasp.perception.fit import FitConfig, fit_pose
from prompose_grasp.perception.priors import PriorLibrary


@pytest.fixture(scope="module")
def mug():
    return PriorLibrary().family_prior("mug")


def _scene(prior, seed: int = 0):
    """Camera-facing samples of the mug's prior posed upright 0.8 m away (2 mm noise), the support plane,
    and a warm start 3 deg and 8 mm off."""
    rng = np.random.default_rng(seed)
    size = np.asarray(prior.typical_size_m, dtype=np.float64)
    up = np.array([0.0, -0.8, -0.6])  # the table's normal in the camera frame (OpenCV: y down)
    x = np.cross(up, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.column_stack([x, up, np.cross(x, up)])
    gt = Pose9D(R, np.array([0.02, 0.05, 0.8]), size)
    pts = gt.points_to_camera(np.asarray(prior.points))
    n_cam = (np.asarray(prior.normals) / size) @ R.T
    pts = pts[np.einsum("ij,ij->i", n_cam, pts) < 0.0] + rng.normal(scale=0.002, size=(1, 3))
    bottom = gt.t - 0.5 * size[1] * up
    plane = np.array([*up, -float(up @ bottom)])
    init = Pose9D(so3_exp(up * math.radians(3.0)) @ R, gt.t + np.array([0.008, 0.0, 0.0]), size * 1.05)
    return pts, plane, init


@pytest.mark.parametrize("scale", [0.0, 1e-12, 1e-9, 1e-3, 0.5, 3.0])
def test_rodrigues_step_is_so3_exp(scale):
    rng = np.random.default_rng(1)
    for _ in range(20):
        w = rng.normal(size=3)
        w *= scale / max(np.linalg.norm(w), 1e-300)
        # double round-off of a 3x3 product: entries agree to a few ulps
        np.testing.assert_allclose(solver._rotvec_matrix(w), so3_exp(w), rtol=0.0, atol=1e-14)


def _problem(prior, pts, plane, init, cfg):
    up = plane[:3]
    obs = observation._subsample(pts, cfg.n_points_warm, "random", cfg.seed)
    pp, pn = problem._prior_subset(prior, cfg.warm_prior_points)
    basis = problem._basis(up, (up, float(plane[3])), prior.symmetry)
    pb = problem._Problem(
        obs, cKDTree(obs), pp, pn, up, (up, float(plane[3])), basis, np.log(prior.aspect), cfg
    )
    bottom = init.t - 0.5 * init.size[1] * up
    bottom = bottom - (bottom @ up + plane[3]) * up
    return pb, problem._State(init.R.copy(), bottom, np.log(init.size))


def test_remembered_evaluation_is_the_fresh_one(mug):
    pts, plane, init = _scene(mug)
    cfg = FitConfig()
    pb, st = _problem(mug, pts, plane, init, cfg)
    with_jac = objective._evaluate(pb, st, True)
    again = objective._evaluate(pb, st, False)  # the same state object: remembered
    assert again is with_jac
    fresh_pb, _ = _problem(mug, pts, plane, init, cfg)
    fresh = objective._evaluate(fresh_pb, st.copy(), False)
    # the same arithmetic on the same numbers: bit for bit
    assert fresh[:3] == with_jac[:3]
    # an equal state that is another object is evaluated again (identity, not equality, is remembered)
    assert objective._evaluate(pb, st.copy(), False) is not with_jac
    # asking for the normal equations after a cost-only evaluation computes them
    cost_only = objective._evaluate(fresh_pb, st, False)
    full = objective._evaluate(fresh_pb, st, True)
    assert full[3] is not None and full[:3] == cost_only[:3]
    np.testing.assert_array_equal(full[3], with_jac[3])


def test_no_iterations_no_normal_equations(mug):
    pts, plane, init = _scene(mug)
    pb, st = _problem(mug, pts, plane, init, FitConfig())
    st2, cost = solver._optimise(pb, st, 0)
    assert st2 is st and pb.memo[1][3] is None  # cost only
    assert cost == objective._evaluate(_problem(mug, pts, plane, init, FitConfig())[0], st, True)[0]


def test_warm_fit_matches_the_plain_computation(mug, monkeypatch):
    pts, plane, init = _scene(mug)
    cfg = FitConfig()
    fast = fit_pose(pts, mug, cfg, init=init, support_plane_cam=plane)
    # undo both shortcuts: scipy's rotation step, and no remembered evaluation
    monkeypatch.setattr(solver, "_rotvec_matrix", so3_exp)
    evaluate = objective._evaluate

    def forgetful(pb, st, want_jacobian):
        pb.memo = None
        return evaluate(pb, st, want_jacobian)

    for module in (core, handle, solver):  # every caller of `_evaluate`
        monkeypatch.setattr(module, "_evaluate", forgetful)
    plain = fit_pose(pts, mug, cfg, init=init, support_plane_cam=plane)
    # the two rotation formulas differ by round-off (1e-16) per step; 8 steps of a well-conditioned
    # Levenberg-Marquardt keep it far below 1e-9 m / 1e-9 rad (measured: 1e-16 on 238 recorded warm fits)
    np.testing.assert_allclose(fast.pose.t, plain.pose.t, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(fast.pose.R, plain.pose.R, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(fast.pose.size, plain.pose.size, rtol=1e-9)
    assert fast.iterations == plain.iterations >= 3  # the steps ran (8 at most, fewer once converged)
    assert math.isclose(fast.robust_loss, plain.robust_loss, rel_tol=1e-9)
