"""Metric 9-DoF fit of a canonical shape prior to the observed points: a test-time minimisation of L_geo.

The paper (section 3.7) trains its network with L_geo, the bidirectional squared Chamfer distance between the
scaled, posed prior `R diag(s) P_prior + T` and the masked observation. Here L_geo is minimised directly for
one frame, over the rotation, the translation and the anisotropic size, from several initial hypotheses.

`fit_pose`'s steps, one module each (docs/fit.md has the reasons for each choice):

1. `inputs`: the arguments checked.
2. `observation`: a depth gate around the [p5, p95] depth range, a voxel subsample to `n_points` (2048,
   paper section 4.1) whose first few hundred points are in farthest-point order for the coarse stages (a
   random subsample on warm starts), and where the image border or an occluder cuts the object off.
3. `hypotheses`: yaws about the support normal, or the signed, permuted PCA axes without one, each with its
   amodal initial box; a warm start `init` is the single hypothesis. An articulated family (a laptop:
   `priors.library.articulated_variants`) adds its other articulations at the best coarse yaw.
4. `solver` on the `objective` (parameters in `problem`): the visibility-aware, robust L_geo minimised by
   ICP-style Levenberg-Marquardt, coarse-to-fine over the hypotheses; the lowest loss wins.
5. `handle`: a mug's handle turned to the yaw its own points give, or, hidden, to the middle of the turns
   that hide it.
6. `surface`, `symmetry`: the box grown out to the seen surface, and the symmetry-canonical pose (equal
   shapes give equal poses).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import so3_exp
from prompose_grasp.perception.fit.handle import _place_handle
from prompose_grasp.perception.fit.hypotheses import (
    _initial_rotations,
    _initial_state,
    _initial_states,
    _warm_state,
)
from prompose_grasp.perception.fit.inputs import _check_inputs
from prompose_grasp.perception.fit.objective import _evaluate
from prompose_grasp.perception.fit.observation import (
    SceneView,
    _cut_edges,
    _Cuts,
    mask_coverage,
    observed_points,
)
from prompose_grasp.perception.fit.problem import _basis, _Problem, _State
from prompose_grasp.perception.fit.solver import _optimise, _Problems, _solve_cold, _solve_warm
from prompose_grasp.perception.fit.surface import grow_to_seen, seen_surface
from prompose_grasp.perception.fit.symmetry import canonicalize_symmetry
from prompose_grasp.perception.fit.types import FitConfig, FitResult
from prompose_grasp.perception.priors.library import articulated_variants, round_body_axis
from prompose_grasp.perception.priors.prior import ShapePrior

__all__ = ["fit_pose"]

log = logging.getLogger(__name__)


def fit_pose(
    points_cam: ArrayLike,
    prior: ShapePrior,
    config: FitConfig | None = None,
    up_cam: ArrayLike | None = None,
    init: Pose9D | None = None,
    support_plane_cam: ArrayLike | None = None,
    scene: SceneView | None = None,
) -> FitResult:
    """Fit the prior's metric 9-DoF box to the observed points by minimising the visibility-aware L_geo.

    Args:
        points_cam: (N, 3) float, metres: the object's masked depth back-projected into the camera frame
            (OpenCV: x right, y down, z forward); finite, z > 0, N >= `config.min_points`.
        prior: the canonical shape prior (unit box, +y up) with normals and symmetry tag.
        config: `FitConfig()` by default.
        up_cam: (3,) the support's up direction in the camera frame (unit or not; it is normalised). When
            given, the object stands upright on the support: its +y is `up_cam` and only yaw is searched.
        init: a warm start (e.g. the previous frame's pose): one hypothesis, fewer iterations, a random
            subsample of `config.n_points_warm` points instead of FPS.
        support_plane_cam: (4,) (nx, ny, nz, d) of the plane the object rests on, n.x + d = 0 in the camera
            frame with n pointing up (towards the object). Implies `up_cam` = n, and holds the box's bottom
            face on the plane: the amodal height reaches the support even where the bottom is hidden.
        scene: the depth image and mask the points came from (`SceneView`), optional: prior points the
            camera could not have seen there (outside the image, no reading, behind an occluder) do not
            pull on the observation (`config.scene_occlusion`).

    Returns:
        FitResult; `pose.size` > 0, `pose.R` symmetry-canonical for the prior's symmetry tag.

    Raises:
        InvalidInputError: wrong shapes, NaN/inf, points behind the camera, too few points, bad up/plane.
    """
    t0 = time.perf_counter()
    inp = _check_inputs(points_cam, prior, config, up_cam, init, support_plane_cam, scene)
    cfg, up, plane, sym = inp.cfg, inp.up, inp.plane, prior.symmetry
    view = scene if cfg.scene_occlusion else None
    warm = init is not None

    pts, obs = observed_points(inp.pts, cfg, warm)
    # Articulated families (a laptop's screen angle) bring variants of the prior; they compete as extra
    # hypotheses at the best yaw of the mean shape (`_solve_cold`). A warm start keeps the shape it was given.
    shapes = (prior, *(articulated_variants(prior) if cfg.articulations and not warm else ()))
    # A warm start has no cut edges: its one stage has the whole scene view.
    cuts = _cut_edges(None if warm else view, pts, cfg.occlusion_margin_m)
    problems = _Problems(obs, shapes, up, plane, _basis(up, plane, sym), cfg, view, cuts)

    if init is not None:
        finals, iterations = _solve_warm(problems, _warm_state(init, up, plane))
        n_hypotheses = 1
    else:
        rotations = _initial_rotations(pts, up, sym, cfg)
        states = _initial_states(pts, rotations, prior, up, plane, cuts.edge)

        def variant_state(R: np.ndarray, shape: ShapePrior) -> _State:
            return _initial_state(pts, R, shape, up, plane, sym, cut_edge=cuts.edge)

        finals, iterations = _solve_cold(problems, states, variant_state)
        n_hypotheses = len(rotations)

    scored = [(_evaluate(pb, st, False), st, pb, k) for st, pb, k in finals]
    value, st, pb, k_best = min(scored, key=lambda s: s[0].cost)
    shape = shapes[k_best]
    if sym == "y_continuous" and up is not None and not warm and cfg.free_section_ratio > 0.0:
        freed = _free_section(pb, st, shape, up, plane, cfg, view, cuts)
        if freed is not None:
            value, st, pb, shape = freed
            sym = shape.symmetry
    body_axis = round_body_axis(shape) if up is not None and cfg.handle_band_tol >= 0.0 else None
    if body_axis is not None and not warm:
        placed = _place_handle(pb, st, body_axis, shape, pts, cfg)
        if placed is not st:
            st, value = placed, _evaluate(pb, placed, False)

    fitted = pb.pose(st)
    surface = seen_surface(fitted, plane, cfg, scene)
    pose = canonicalize_symmetry(grow_to_seen(fitted, sym, plane, cfg, scene, surface), sym, up)
    result = FitResult(
        pose=pose,
        loss=value.obs_to_prior + value.prior_to_obs,
        obs_to_prior=value.obs_to_prior,
        prior_to_obs=value.prior_to_obs,
        robust_loss=value.cost,
        hypotheses=n_hypotheses,
        hypothesis_losses=tuple(s[0].cost for s in scored),
        iterations=iterations,
        n_points=len(obs),
        mode=("warm_" if warm else "") + _mode(up, plane),
        time_s=time.perf_counter() - t0,
        prior=shape,
        coverage=math.nan if scene is None else mask_coverage(pose, shape, scene),
        surface_points=surface if scene is not None else None,
    )
    log.debug("fit %s: loss %.3g m^2, %d hypotheses, %d iterations", prior.name, result.loss,
              result.hypotheses, result.iterations)  # fmt: skip
    return result


def _free_section(
    pb_round: _Problem,
    st: _State,
    shape: ShapePrior,
    up: np.ndarray,
    plane: tuple[np.ndarray, float] | None,
    cfg: FitConfig,
    view: SceneView | None,
    cuts: _Cuts,
) -> tuple[Any, _State, _Problem, ShapePrior] | None:
    """The round-section fit of a body of revolution released to two section widths, free of the family's
    section aspect (`FitConfig.free_section_ratio`): a family chosen from the words ("bottle", "can") may
    be round where the object is not (a squeeze bottle, a meat can); the data then decide. The free fit
    starts at the round solution turned by 0 and 45 degrees about the up direction (its widths are equal
    there, so either may grow) and is kept when its loss is under `free_section_ratio` times the round
    solution's on the same terms; its prior is the same shape with the symmetry of an elliptical section
    (`y_2fold`). None: the round section stays."""
    free = dataclasses.replace(shape, symmetry="y_2fold")
    problems = _Problems(pb_round.obs, (free,), up, plane, _basis(up, plane, "y_2fold"), cfg, view, cuts)
    # Judged on the schedule's next-to-last stage (a coarser cloud: a fifth of the full one's cost per
    # iteration), refined on the full clouds only when kept.
    trial = cfg.stages[-2] if len(cfg.stages) > 1 else cfg.stages[-1]
    pb = _without_section_aspect(
        problems.get(0, min(trial.obs_points, len(pb_round.obs)), trial.prior_points)
    )
    round_cost = _evaluate(pb, st, False).cost
    best: tuple[float, _State] | None = None
    for yaw in (0.0, 0.25 * math.pi):
        start = _State(so3_exp(yaw * up) @ st.R, st.b.copy(), st.log_s.copy())
        end, cost = _optimise(pb, start, trial.iterations)
        if best is None or cost < best[0]:
            best = (cost, end)
    assert best is not None
    cost, end = best
    log.debug("free section: loss %.3g of the round section's %.3g", cost, round_cost)
    if not (round_cost > 0.0 and cost < cfg.free_section_ratio * round_cost):
        return None
    full = _without_section_aspect(problems.get(0, len(pb_round.obs), len(pb_round.prior_p)))
    end, _ = _optimise(full, end, cfg.stages[-1].iterations)
    return _evaluate(full, end, False), end, full, free


def _without_section_aspect(pb: _Problem) -> _Problem:
    """`pb` with no prior on the x:z aspect (the section's, which a free-section fit frees)."""
    pb.aspect_factors = pb.aspect_factors * np.array([1.0, 1.0, 0.0])
    return pb


def _mode(up: np.ndarray | None, plane: tuple[np.ndarray, float] | None) -> str:
    """The fit's mode: "upright_plane" with a support plane, "upright" with an up direction only, else
    "free"."""
    return "upright_plane" if plane is not None else ("upright" if up is not None else "free")
