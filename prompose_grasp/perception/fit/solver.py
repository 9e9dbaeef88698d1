"""The fit's minimisation: Levenberg-Marquardt on one hypothesis (`_optimise`), and the coarse-to-fine
schedule over all of them (`_solve_cold`, `_solve_warm`).

ICP-style: the nearest neighbours are found again at every iteration (`objective._evaluate`), then a damped
Gauss-Newton step on them. A cold start runs every hypothesis through the first, coarse stage on subsampled
clouds; after each stage the `keep` lowest-loss ones go on to the next, finer one; the last stage refines
the survivors on the full clouds. A warm start runs its single hypothesis once, with the whole scene view.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from prompose_grasp.geometry.se3 import hat
from prompose_grasp.perception.fit.objective import _evaluate
from prompose_grasp.perception.fit.observation import SceneView, _Cuts
from prompose_grasp.perception.fit.problem import LOG_SIZE, ROT, TRANS, _prior_subset, _Problem, _State
from prompose_grasp.perception.fit.types import FitConfig
from prompose_grasp.perception.priors.library import aspect_weight_factors
from prompose_grasp.perception.priors.prior import ShapePrior

#: Sizes are kept in [1 mm, 20 m]: outside that range a fit has diverged, whatever the object.
_LOG_SIZE_MIN, _LOG_SIZE_MAX = math.log(1e-3), math.log(20.0)


def _rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (3,) by Rodrigues' formula: `so3_exp` up to round-off, without
    scipy's per-call overheads (it runs once per Levenberg-Marquardt step)."""
    theta2 = float(w @ w)
    W = hat(w)
    if theta2 < 1e-16:  # second-order series: exact to double precision below 1e-8 rad
        return np.eye(3) + W + 0.5 * (W @ W)
    theta = math.sqrt(theta2)
    return np.eye(3) + (math.sin(theta) / theta) * W + ((1.0 - math.cos(theta)) / theta2) * (W @ W)


def _apply(pb: _Problem, st: _State, delta: np.ndarray) -> _State:
    """`st` moved by the reduced step `delta` (D,): rotated on the left, moved, resized (sizes clipped)."""
    full = pb.basis @ delta
    return _State(
        _rotvec_matrix(full[ROT]) @ st.R,
        st.b + full[TRANS],
        np.clip(st.log_s + full[LOG_SIZE], _LOG_SIZE_MIN, _LOG_SIZE_MAX),
    )


def _optimise(pb: _Problem, st: _State, iterations: int) -> tuple[_State, float]:
    """Levenberg-Marquardt on the robust objective with correspondences re-found every iteration."""
    cost, _, _, H, g = _evaluate(pb, st, iterations > 0)  # no iteration, no normal equations
    mu = pb.config.damping
    for _ in range(iterations):
        pb.iterations += 1
        assert H is not None and g is not None
        scale = float(np.mean(np.diag(H))) or 1.0
        D = H.shape[0]
        try:
            delta = -np.linalg.solve(H + (mu * scale) * np.eye(D), g)
        except np.linalg.LinAlgError:
            break
        trial = _apply(pb, st, delta)
        t_cost = _evaluate(pb, trial, False)[0]  # the normal equations only for a step that is taken
        if t_cost <= cost:
            taken = _evaluate(pb, trial, True)
            st, cost, H, g = trial, t_cost, taken.H, taken.g
            mu = max(mu / 3.0, pb.config.damping)
            if float(np.max(np.abs(delta))) < pb.config.step_tol:
                break
        else:
            mu *= 10.0
            if mu > 1e6:
                break
    return st, cost


class _Problems:
    """The `_Problem` of each shape, cloud sizes and use of the scene view in one `fit_pose` call, built on
    first use: hypotheses of one stage share it, and problems with the same observed points share their
    k-d tree.

    `obs` is in farthest-point order (`observation.observed_points`): a prefix is a coarser sample. The
    scene view is used in the last `occlusion_stages` stages, or in every stage when an occluder cuts the
    object (its seen sliver alone fits a thin slab best: the right box lost the coarse ranking, dev split
    29); coarse stages of an object the image border cuts off still know the image's bounds.
    """

    def __init__(
        self,
        obs: np.ndarray,
        shapes: Sequence[ShapePrior],
        up: np.ndarray | None,
        plane: tuple[np.ndarray, float] | None,
        basis: np.ndarray,
        cfg: FitConfig,
        view: SceneView | None,
        cuts: _Cuts,
    ) -> None:
        self.obs, self.shapes, self.up, self.plane, self.basis = obs, shapes, up, plane, basis
        self.cfg, self.view, self.cuts = cfg, view, cuts
        # a body of revolution: the containment term holds the points in its inscribed cylinder
        self.round_section = shapes[0].symmetry == "y_continuous"
        self._built: dict[tuple[int, int, int, bool, bool], _Problem] = {}

    def get(self, k_shape: int, n_o: int, n_p: int, k_stage: int | None = None) -> _Problem:
        """The problem of shape `k_shape` (0: the prior, then its articulated variants) on the first `n_o`
        observed and `n_p` prior points, in stage `k_stage` (default: the last)."""
        cfg, view = self.cfg, self.view
        if k_stage is None:
            k_stage = len(cfg.stages) - 1
        late = k_stage >= len(cfg.stages) - cfg.occlusion_stages
        with_view = view is not None and (late or self.cuts.by_occluder)
        image_only = not with_view and self.cuts.by_image
        key = (k_shape, n_o, n_p, with_view, image_only)
        pb = self._built.get(key)
        if pb is None:
            o = self.obs[:n_o]
            shp = self.shapes[k_shape]
            pp, pn = _prior_subset(shp, n_p)
            tree = next((q.obs_tree for (_, m, *_), q in self._built.items() if m == n_o), None)
            pb = _Problem(
                obs=o,
                obs_tree=tree or cKDTree(o),
                prior_p=pp,
                prior_n=pn,
                up=self.up,
                plane=self.plane,
                basis=self.basis,
                log_aspect=np.log(shp.aspect),
                config=cfg,
                scene=view if with_view or image_only else None,
                round_section=self.round_section,
                scene_image_only=image_only,
                aspect_factors=aspect_weight_factors(shp),
            )
            self._built[key] = pb
        return pb


#: A hypothesis at the end of the schedule: its state, the problem it was optimised on, its shape's index.
_Final = tuple[_State, _Problem, int]


def _solve_warm(problems: _Problems, state: _State) -> tuple[list[_Final], int]:
    """The warm start's one hypothesis optimised on all its points; and the iterations it took."""
    cfg = problems.cfg
    pb = problems.get(0, len(problems.obs), cfg.warm_prior_points)
    st, _ = _optimise(pb, state, cfg.warm_iterations)
    return [(st, pb, 0)], pb.iterations


def _solve_cold(
    problems: _Problems, states: list[_State], variant_state: Callable[[np.ndarray, ShapePrior], _State]
) -> tuple[list[_Final], int]:
    """The cold start's hypotheses through the coarse-to-fine schedule (`FitConfig.stages`): the survivors
    of the last stage, and the iterations of all stages. After the first stage each articulated variant of
    the prior (`problems.shapes[1:]`) joins as a hypothesis at the best rotation found for the mean shape,
    with its own amodal initial box (`variant_state(R, shape)`)."""
    cfg, variants = problems.cfg, problems.shapes[1:]
    total_iters = 0
    hyps = [(st, 0) for st in states]
    finals: list[_Final] = []
    for k, stage in enumerate(cfg.stages):
        n_o = min(stage.obs_points, len(problems.obs))
        ranked = []
        for st, ks in hyps:
            pb = problems.get(ks, n_o, stage.prior_points, k)
            it0 = pb.iterations
            st2, cost = _optimise(pb, st, stage.iterations)
            total_iters += pb.iterations - it0
            ranked.append((cost, st2, ks))
        if k == 0 and variants:
            best_R = min(ranked, key=lambda r: r[0])[1].R
            for kv, shp in enumerate(variants, start=1):
                pb = problems.get(kv, n_o, stage.prior_points, k)
                it0 = pb.iterations
                st2, cost = _optimise(pb, variant_state(best_R, shp), stage.iterations)
                total_iters += pb.iterations - it0
                ranked.append((cost, st2, kv))
        order = np.argsort([r[0] for r in ranked], kind="stable")
        last = k == len(cfg.stages) - 1
        keep = stage.keep + (len(variants) if k == 0 else 0)
        hyps = [(ranked[i][1], ranked[i][2]) for i in (order if last else order[:keep])]
        finals = [(st, problems.get(ks, n_o, stage.prior_points, k), ks) for st, ks in hyps]
    return finals, total_iters
