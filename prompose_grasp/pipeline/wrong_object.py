"""No wrong-object success: after the lift the prompt is estimated again; the candidate nearest the tcp and
risen from where the object stood is what is held. When another candidate, standing where the camera saw an
object before the pick (or where the picked object hid it), fits the prompt clearly better
(`PickConfig.wrong_object_margin` on the calibrated `probability`) and about as well as the object chosen
before the pick did (the held one, in the air behind the jaws, reads low whatever it is), or the prompt names
a colour the held object clearly lacks while the other shows it, the object is put back (the lift line back
down to its grasp pose, validated first, then open and retreat) and the attempt ends "wrong_object". Without
probabilities, masks or a held candidate the check cannot judge and passes: it never invents a wrong object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from prompose_grasp.errors import UnreachableError, UnsafeCommandError
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import invert_T, transform_points
from prompose_grasp.grasp.types import Grasp
from prompose_grasp.perception.grounding.confidence import ConfidenceModel
from prompose_grasp.perception.grounding.score import total_of_score
from prompose_grasp.pipeline.candidates import SAME_PLACE_M, any_will_do
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.describe import colour_share, object_noun, phrase, positions, prompt_colour
from prompose_grasp.pipeline.hand import release_and_back_off
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.seams import ObjectEstimate
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = [
    "HELD_XY_SLACK_M",
    "REVEALED_GAP_M",
    "REVEALED_MIN_POINTS",
    "STOOD_MARGIN_M",
    "STOOD_MIN_POINTS",
    "across",
    "put_back",
    "revealed",
    "rose_since",
    "wrong_object",
]

#: After the lift, the held object's centre lies across from the tcp by at most half its largest extent (a
#: grasp on a side face) plus this: the estimate of an object half hidden in the hand is off by 1-2 cm [m].
HELD_XY_SLACK_M = 0.03
#: A candidate stood there before the pick when the pick's observed points, above the support by more than
#: this, lie inside its box grown by this: the fitted box's faces are ~1 cm off the surface it was fitted to,
#: and the table's own points stay under it [m] ...
STOOD_MARGIN_M = 0.01
#: ... at least this many of them: the observation is thinned to `max_scene_points` (every 7th point of 640 x
#: 480), which leaves ~200 on the top of a 5 cm object at 0.8 m (fx 600 px); 20 is a corner of one [-].
STOOD_MIN_POINTS = 20
#: A box was hidden behind the picked object before the pick (`revealed`) when this many of its 8 corners and
#: centre project onto readings of the picked object ...
REVEALED_MIN_POINTS = 5
#: ... nearer than themselves by this: an occluder in front, not the same surface (depth noise at 1 m is
#: a few mm; two objects standing one behind the other are centimetres apart) [m].
REVEALED_GAP_M = 0.02
#: A held object whose visible pixels are under this share of the colour the prompt names clearly is not of
#: that colour: one that is keeps far more even half hidden by the jaws (a green bottle with a white label),
#: while a few percent are edge pixels blended with what lies behind [-] ...
_COLOUR_ABSENT = 0.03
#: ... while another candidate shows it on at least this share: that colour, not a printed detail [-].
_COLOUR_SHOWN = 0.25
#: A standing candidate "fits about as well" as the object chosen before the pick when its score total is
#: within this of the chosen one's: T ln 2 of the grounder's calibration (`confidence.ConfidenceModel`),
#: odds within a factor of two.
_AS_WELL_AS_TOTAL = ConfidenceModel().temperature * math.log(2.0)


def across(a: np.ndarray, b: np.ndarray) -> float:
    """Horizontal distance of two base-frame points (across base +z) [m]."""
    return float(np.linalg.norm((np.asarray(a) - np.asarray(b))[:2]))


def _total(est: ObjectEstimate) -> float:
    """The grounder's score total of an estimate (`grounding.score.total_of_score`; -inf without a score)."""
    s = float(getattr(est, "score", float("nan")))
    return -math.inf if math.isnan(s) else float(total_of_score(min(max(s, 0.0), 1.0)))


def _probability(est: ObjectEstimate) -> float:
    """The estimate's calibrated probability of being the object named (NaN when not computed)."""
    return float(getattr(est, "probability", math.nan))


def _in_box(points: np.ndarray, pose_base: Pose9D, grow_m: float) -> np.ndarray:
    """(N,) bool: the base-frame `points` inside the box `pose_base` grown by `grow_m` on every side."""
    local = (points - pose_base.t) @ pose_base.R
    return np.all(np.abs(local) <= 0.5 * np.asarray(pose_base.size) + grow_m, axis=1)


def _heights_before(pose_base: Pose9D, obs: Observation) -> np.ndarray:
    """Heights above the support [m] of the pick's observed points inside the box grown by `STOOD_MARGIN_M`,
    those more than that above it (the table's own points under the box are not an object's); the
    observation must have a support."""
    assert obs.support is not None
    P = obs.points_base[_in_box(obs.points_base, pose_base, STOOD_MARGIN_M)]
    heights = P @ np.asarray(obs.support.normal) + obs.support.offset_m
    return heights[heights > STOOD_MARGIN_M]


def rose_since(pose_base: Pose9D, obs: Observation, lowest_now: float, rise: float) -> bool:
    """What the camera sees of this box now lies `rise` higher than what it saw there before the pick: its
    lowest seen points (`lowest_now`, above the support) against the 5th percentile height of the pick's
    observed points inside the box (grown by `STOOD_MARGIN_M`). An unmoved object shows the same surface to
    the same camera (its top from above, down to its base from the side); a part of the lifted object
    hanging beside the hand shows only points in the air. False where nothing was seen there before."""
    if obs.support is None or not math.isfinite(lowest_now):
        return False
    heights = _heights_before(pose_base, obs)
    if len(heights) < STOOD_MIN_POINTS:
        return False
    return lowest_now - float(np.percentile(heights, 5.0)) >= rise


def stood_before(pose_base: Pose9D, obs: Observation) -> bool:
    """The camera saw an object inside this box before the pick: `STOOD_MIN_POINTS` of the pick's observed
    points in it (grown by `STOOD_MARGIN_M`), above its support plane (without a plane: in the box)."""
    if obs.support is None:
        return int(np.count_nonzero(_in_box(obs.points_base, pose_base, 0.0))) >= STOOD_MIN_POINTS
    return len(_heights_before(pose_base, obs)) >= STOOD_MIN_POINTS


def revealed(pose_base: Pose9D, obs: Observation) -> bool:
    """The camera could not see this box before the pick because the picked object stood in front of it:
    at least `REVEALED_MIN_POINTS` of its 8 corners and centre project, in the pick's frame, onto readings
    nearer than themselves by `REVEALED_GAP_M` that lie on the picked object (its box grown by
    `STOOD_MARGIN_M`). Lifting an object shows what stood behind it: a can hidden behind a bigger one."""
    frame = obs.frame
    if frame is None or frame.T_base_cam is None:
        return False
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    pts = transform_points(invert_T(T_base_cam), np.vstack([pose_base.corners(), pose_base.t[None]]))
    intr, depth = frame.intrinsics, np.asarray(frame.depth_m, dtype=np.float64)
    ahead = pts[:, 2] > 0.0
    uv = np.full((len(pts), 2), -1, dtype=np.int64)
    uv[ahead] = np.round(intr.project(pts[ahead])).astype(np.int64)
    ok = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
    d = np.zeros(len(pts))
    d[ok] = depth[uv[ok, 1], uv[ok, 0]]
    nearer = ok & np.isfinite(d) & (d > 0.0) & (d < pts[:, 2] - REVEALED_GAP_M)
    if np.count_nonzero(nearer) < REVEALED_MIN_POINTS:
        return False
    # the nearer readings, back in base: on the picked object?
    rays = np.column_stack(
        [(uv[nearer, 0] - intr.cx) / intr.fx, (uv[nearer, 1] - intr.cy) / intr.fy, np.ones(int(nearer.sum()))]
    )
    seen_base = transform_points(T_base_cam, rays * d[nearer, None])
    on_target = _in_box(seen_base, obs.target.pose, STOOD_MARGIN_M)
    return int(np.count_nonzero(on_target)) >= REVEALED_MIN_POINTS


def wrong_object(
    loop: Loop,
    cmd: Command,
    obs: Observation,
    frame: RGBDFrame,
    ests: Sequence[ObjectEstimate],
    lowest_seen: Sequence[float],
) -> tuple[ObjectEstimate, ObjectEstimate, str] | None:
    """(held, the candidate that should have been picked, why) when the re-observation after the lift
    says the held object is not the one named; None when it is, or when it cannot tell (fails closed).

    The held object is the candidate nearest the tcp among those hanging under it (centre within half
    the object's largest extent plus `HELD_XY_SLACK_M` of the tcp, across, and risen by `moved_min_m` or
    more from where the object stood: its box's centre, or its lowest seen points, `lowest_seen` per
    estimate: the 5th percentile of `verify.seen_heights`). The others count when they stand (not
    `rose_since`: a bowl hanging from its rim far from the tcp, seen in two pieces, is not standing) away
    from the tcp and from where the object was picked (`SAME_PLACE_M`), where the camera saw an object
    before the pick (`stood_before`) or could not see, behind the picked object (`revealed`). Wrong: one of
    them fits the prompt clearly better (`wrong_object_margin`) and about as well as the object chosen
    before the pick (`_AS_WELL_AS_TOTAL`; only for a command naming one object with `candidate_order`
    "score"), or the prompt names a colour the held object's visible pixels clearly lack (`_COLOUR_ABSENT`)
    while one of them shows it (`_COLOUR_SHOWN`)."""
    if len(ests) < 2:
        return None
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    tcp = np.asarray(loop.robot.fk_tcp(loop.arm.joint_positions()), dtype=np.float64)[:3, 3]
    poses = [e.pose.transformed(T_base_cam) for e in ests]
    reach = 0.5 * float(np.max(obs.target.pose.size)) + HELD_XY_SLACK_M
    # held: under the tcp, and risen from where the object stood (an object still on the table under the
    # lifted hand, a cup beside the bowl that was taken, is not in the hand): its box's centre rose, or
    # even its lowest seen points are that high above the support (seen in the air and partly behind
    # the jaws, a held object's amodal box can reach down to the table)
    rise = loop.config.moved_min_m
    hanging = [
        k
        for k, p in enumerate(poses)
        if across(p.t, tcp) <= reach and (p.t[2] - obs.target.pose.t[2] >= rise or lowest_seen[k] >= rise)
    ]
    if not hanging:
        return None  # the held object is not among the candidates: nothing to judge
    k_held = min(hanging, key=lambda k: float(np.linalg.norm(poses[k].t - tcp)))
    held = ests[k_held]
    standing = [
        e
        for k, (e, p) in enumerate(zip(ests, poses))
        if k != k_held
        and min(across(p.t, tcp), across(p.t, obs.target.pose.t)) > SAME_PLACE_M
        and not rose_since(p, obs, lowest_seen[k], rise)
        and (stood_before(p, obs) or revealed(p, obs))
    ]
    if not standing:
        return None
    p_held = _probability(held)
    judged = [e for e in standing if math.isfinite(_probability(e))]
    if judged and math.isfinite(p_held) and not any_will_do(cmd, loop.config):
        other = max(judged, key=_probability)
        # The held object is seen in the air and partly behind the jaws, so its own probability reads
        # low whatever it is; a standing one only counts when it also fits the words about as well as
        # the object chosen before the pick did (measured the same way, standing on the table)
        as_well = _total(other) >= _total(obs.estimate) - _AS_WELL_AS_TOTAL
        if as_well and _probability(other) - p_held > loop.config.wrong_object_margin:
            return held, other, f"p {p_held:.2f} against {_probability(other):.2f}"
    colour = prompt_colour(cmd.object_prompt)
    if colour is None:
        return None

    def share(e: ObjectEstimate) -> float:
        return colour_share(frame.rgb, getattr(e, "mask", None), colour, frame.depth_m)

    s_held = share(held)
    shown = [(share(e), e) for e in standing]
    shown = [(s, e) for s, e in shown if math.isfinite(s)]
    if not (shown and math.isfinite(s_held) and s_held < _COLOUR_ABSENT):
        return None
    s_other, other = max(shown, key=lambda se: se[0])
    if s_other < _COLOUR_SHOWN:
        return None
    return held, other, f"{100 * s_held:.0f} % {colour} pixels against {100 * s_other:.0f} %"


def put_back(
    loop: Loop,
    run: RunRecord,
    cmd: Command,
    obs: Observation,
    grasp: Grasp,
    frame: RGBDFrame,
    held: ObjectEstimate,
    other: ObjectEstimate,
    why: str,
) -> None:
    """Put the wrong object back where it stood (the lift line back down to the grasp pose, validated
    before it is sent, then `release_and_back_off`), and end the attempt "wrong_object"."""
    cfg = loop.config
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    seen = getattr(getattr(held, "attributes", None), "description", "") or "another object"
    # Where the one named stands, from the camera, relative to where the held one stood.
    stood_cam = transform_points(invert_T(T_base_cam), obs.target.pose.t[None])[0]
    where = positions(np.array([np.asarray(other.pose.t, dtype=np.float64), stood_cam]))[0]
    named = phrase(other, object_noun(cmd.object_prompt), where, T_base_cam)
    message = f"holding {seen}, not {cmd.object_prompt!r} ({why}): that is more likely {named}"
    loop.emit("verify", f"wrong object: {message}; putting it back", 0.85)
    try:
        for T in (grasp.T_base_tcp, grasp.T_base_retreat):
            loop.validator.validate_linear_move(T, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
        loop.arm.move_linear(grasp.T_base_tcp, cfg.linear_speed_m_s, cfg.linear_accel_m_s2)
    except (UnreachableError, UnsafeCommandError) as exc:
        raise Abort("wrong_object", f"{message}; it could not be put back ({exc}): still held") from None
    release_and_back_off(loop, run, grasp)
    raise Abort(
        "wrong_object",
        f"{message}; put it back where it stood",
        held_at=np.array(obs.target.pose.t),
        retry_at=np.array(other.pose.transformed(T_base_cam).t),
    )
