"""Which object: the estimator's candidates for the prompt that count as "the object", in the order they
are tried.

Candidates whose grounding score is within `candidate_ratio` of the best are all "the object" (identical
cartons on a pallet); with `candidate_order="top_first"` they are tried from the highest top down (what lies
on top of a pile first), with `"score"` (a tabletop of different things, where a 90 % candidate is often
another object) best match first; any already at the place target is skipped. The first observation of an
object judges ambiguity (`observe.estimates_once`) unless the command takes any object that fits: a plural
one, or `candidate_order` "top_first" (like things).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.se3 import transform_points
from prompose_grasp.grasp.extent import top_height
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.place_targets import at_target
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.config import PickConfig
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation, estimates, to_base
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["SAME_PLACE_M", "any_will_do", "observe_candidates", "score"]

logger = logging.getLogger(__name__)

#: A candidate this close to where the object of a failed round stood is that object [m]: a slipped grasp
#: nudges it a few centimetres; two tabletop objects stand at least ~10 cm centre to centre.
SAME_PLACE_M = 0.06


def any_will_do(cmd: Command, config: PickConfig) -> bool:
    """Any object that fits the prompt will do: a plural command, or a stack of like things
    (`candidate_order` "top_first"); else the command names one object, and which one matters."""
    return cmd.plural or config.candidate_order == "top_first"


def score(obs: Observation) -> float:
    """The grounding score of an observation's estimate (1 for estimators without one)."""
    return float(getattr(obs.estimate, "score", 1.0))


def _size_ratio(size: np.ndarray, ref_sorted: np.ndarray) -> float:
    """The largest factor between a box's sorted extents and the reference's (1 for the same size)."""
    a = np.maximum(np.sort(np.asarray(size, dtype=np.float64)), 1e-6)
    b = np.maximum(np.asarray(ref_sorted, dtype=np.float64), 1e-6)
    return float(np.max(np.maximum(a / b, b / a)))


def _ordered(observations: list[Observation], config: PickConfig) -> list[Observation]:
    """The candidates in the order they are tried (`candidate_order`, then the alike in size first)."""
    if config.candidate_order == "top_first":
        # What lies on top first (the top layer of a stack): highest top along the support normal.
        observations.sort(key=lambda o: -top_height(o.target, o.support))
    else:  # "score": the best match first (candidates come best first)
        observations.sort(key=lambda o: -score(o))
    ratio = config.candidate_max_size_ratio
    if ratio is not None and observations:
        # Candidates unlike the best match in size (a box 6x taller than the tea box it scored next to)
        # are another thing: tried after the alike ones, each group in the order above.
        ref = np.sort(max(observations, key=score).target.pose.size)
        alike = [_size_ratio(o.target.pose.size, ref) <= ratio for o in observations]
        observations = [o for o, a in zip(observations, alike) if a] + [
            o for o, a in zip(observations, alike) if not a
        ]
    return observations


def observe_candidates(
    loop: Loop,
    run: RunRecord,
    cmd: Command,
    fixture: PlaceTarget | None,
    round_: int,
    tried_at: np.ndarray | None = None,
    avoid: Sequence[np.ndarray] = (),
) -> tuple[list[Observation], RGBDFrame]:
    """Observe and estimate; the candidates that count as the object, in the order they are tried.

    `tried_at`: where the object of a failed round stood (base) [m], with `candidate_order` "score" (a
    tabletop of different things; in a stack of like things another one will do: a top carton that cannot
    be carried past the forearm leaves its neighbour for the next round). Objects do not move by
    themselves: a candidate still there (within `SAME_PLACE_M`) is tried first, whatever its score this time
    (a noisy frame can rank a neighbour higher, or put the target's score under `candidate_ratio`).

    `avoid`: where a wrong object was put back (base) [m]; a candidate there (within `SAME_PLACE_M`) is
    not tried."""
    cfg = loop.config
    frac = min(round_ / cfg.max_estimates, 1.0)
    q_seen = loop.joints()
    loop.emit("observe", f"observing ({cfg.observe_frames} frame(s))", 0.05 + 0.9 * frac)
    ratio = cfg.candidate_ratio if tried_at is None else 0.0
    judge = tried_at is None and not any_will_do(cmd, cfg)
    frame, ests = estimates(loop, run, cmd.object_prompt, ratio, judge)
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    points = transform_points(T_base_cam, back_project(frame.depth_m, frame.intrinsics))
    stride = max(1, len(points) // cfg.max_scene_points)
    points = points[::stride]
    best = max(float(getattr(e, "score", 1.0)) for e in ests)
    observations, still_there = [], []
    for est in ests:
        target, support = to_base(est, T_base_cam, "target")
        if any(np.linalg.norm(target.pose.t - p) <= SAME_PLACE_M for p in avoid):
            continue  # the wrong object, put back
        if tried_at is not None and np.linalg.norm(target.pose.t - tried_at) <= SAME_PLACE_M:
            still_there.append(Observation(frame, est, target, support, points, q_seen))
            continue
        if float(getattr(est, "score", 1.0)) < cfg.candidate_ratio * best:
            continue
        if fixture is not None and at_target(target, fixture):
            continue  # already where the command wants it
        observations.append(Observation(frame, est, target, support, points, q_seen))
    if not observations and not still_there:
        if avoid:
            raise Abort("not_found", f"no {cmd.object_prompt!r} in view but the wrong object put back")
        raise Abort("not_found", f"every {cmd.object_prompt!r} in view is already on the {cmd.target}")
    observations = _ordered(observations, cfg)
    if still_there:
        assert tried_at is not None
        still_there.sort(key=lambda o: float(np.linalg.norm(o.target.pose.t - tried_at)))
        observations = still_there + observations
    logger.info(
        "candidates for %r: %s",
        cmd.object_prompt,
        "; ".join(f"{score(o):.3f} at {np.round(o.target.pose.t, 3).tolist()}" for o in observations),
    )
    loop.recorder.candidates(observations)
    chosen = observations[0]
    run.acted_on(chosen.estimate, T_base_cam)
    pose_base = chosen.target.pose
    loop.emit(
        "estimate",
        f"{cmd.object_prompt!r}: {chosen.estimate.prior.name} at {np.round(pose_base.t, 3).tolist()} m, "
        f"size {np.round(pose_base.size, 3).tolist()} m ({len(observations)} candidate(s))",
        0.15 + 0.9 * frac,
    )
    return observations, frame
