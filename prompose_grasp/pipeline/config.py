"""`PickConfig`: the settings of the closed loop, validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp import GraspConfig

__all__ = ["CANDIDATE_ORDERS", "PickConfig"]

#: `PickConfig.candidate_order` choices.
CANDIDATE_ORDERS = ("top_first", "score")


@dataclass(frozen=True)
class PickConfig:
    """Settings of the closed loop.

    Attributes:
        max_estimates: observe-estimate-plan rounds (a slip or a moved object starts a new round).
        grasps_per_estimate: grasps of one plan tried (best first) before re-estimating.
        camera_retries: captures tried per observation before "camera_failed" (dropped frames are retried).
        observe_frames: frames per observation; more than one runs the estimator's tracker over them and
            keeps the last (temporally refined) estimate.
        timeout_s: wall-time budget of a run [s].
        joint_speed_rad_s, joint_accel_rad_s2: free moves to the pre-grasp [rad/s, rad/s^2].
        linear_speed_m_s, linear_accel_m_s2: approach and lift lines [m/s, m/s^2].
        grip_force_n: jaw force per finger [N] (suction holds with the cup's full `max_force_n`).
        min_jaw_width_m: jaws closed narrower than this held nothing [m] (the 2F-85 class stops at 0); for a
            grasp planned on a thinner part (a cup's wall) half its planned width, at least 1 mm.
        moved_min_m: on re-observation the object counts as picked when its estimate's centre moved or its
            top rose more than this (or it is no longer seen where it stood) [m]. A third of the 10 cm
            lift: a bowl held by its rim hangs tilted and its estimate rose only 49-50 mm (a 5 cm
            threshold drops it as "still where it stood"), while an unmoved object's re-estimate moves ~1-2 cm
            (noise, the gripper above it).
        max_scene_points: observed points handed to the collision scene (evenly thinned) [-].
        reobserve: re-observe after the lift to confirm the pick.
        open_margin_m: the jaws open this much wider than the object plus the planner's clearance before the
            approach (not the full stroke: a narrower hand fits between neighbours) [m]. It is planned in:
            the grasp's opening, and so the approach's collision check, include it.
        candidates: estimator candidates considered per observation (estimators with `estimate_all`).
        candidate_ratio: candidates scoring at least this fraction of the best one count as the object [-].
        candidate_order: the order those candidates are tried in: "top_first" (highest top first: the top
            layer of a stack of like objects, a pallet of cartons) or "score" (the best match first: a
            tabletop of different things, where a candidate at 90 % of the best score is often another
            object, e.g. a tea box's 0.76 next to its 0.84 on a bottle and a can behind it).
        candidate_max_size_ratio: or None; else candidates whose box differs from the best match's by more
            than this factor in any (sorted) extent are tried after the alike ones: another kind of thing
            (a 0.5 m "tea box" over a bottle and a can, next to the 12 cm tea box that scored best).
        max_objects: objects moved by one plural command at most.
        lift_clearance_m: the lift after a grasp rises at least the object's estimated height plus this, so
            the held object clears what stood beside it (cartons in a layer) [m].
        max_lift_m: ... but at most this [m].
        max_object_height_m: the tallest object the cell handles [m], or None. A box estimated taller (an
            amodal box reaching down to the floor through a stack: from above, the height of a carton on
            other cartons is not seen) is carried and put down as this tall, its top kept: the transfer
            clears the neighbours and the place releases just above the surface.
        wrist_look_m: with a wrist camera, the arm first looks at the target from the best grasp's pre-grasp
            raised this much more; the closer estimate replaces the fixed camera's and the grasps are planned
            again on it (tracking the target on approach) [m].
        wrist_max_shift_m: a wrist estimate farther than this from the fixed camera's is another object and
            is ignored [m].
        pad_depth_margin_m: jaw grasps with the pads' centre this much deeper than half a pad inside the
            estimated box are tried first (robust to the estimate's ~1 cm error) [m].
        self_filter_margin_m: depth readings within this of the arm's and gripper's capsules at the joints of
            the capture are the robot itself and are dropped before estimating (robot self-filtering: a link
            in view is otherwise grounded as an object), or None to keep them [m].
        wrong_object_margin: after the lift, a still standing candidate whose calibrated `probability`
            exceeds the held object's by more than this means the wrong object was picked [-]. The held
            object is seen lifted and partly hidden by the gripper, which lowers its own match (its height
            above the table, size class and shape are measured on that view), so a small lead of a standing
            object is no evidence; the probabilities sum to at most 1, so a lead of 0.3 leaves the held one
            at most 0.35 and the other at least ~1.9 times as likely. Judged only for a command naming one
            object with `candidate_order="score"`: a plural command or a stack takes any object that fits.
        retry_wrong_object: after putting a wrong object back, try the candidate that fits better, once;
            False ends the run "wrong_object".
        approach_contact_force_n: a parallel-jaw approach is a guarded move on an arm that measures the force
            at its tool (`Arm.senses_contact`): it stops where the force exceeds this [N], backs off to the
            pre-grasp and the attempt ends "collision" (the next grasp is tried). The fitted box or mesh can
            leave out a part of the object that nobody saw (an ear on its far side), and open jaws coming down
            on it at the approach speed would otherwise press on until the controller's own force limit
            (150 N on a UR e-Series) stops the arm for good. 40 N lies well above the noise of a UR's tool
            force estimate (a few N) and the inertia of a 1-2 kg gripper at the approach's 1 m/s^2, and well
            under that limit. None: an unguarded approach. A suction cup's approach ends pressed on its
            object by design and is never guarded.
        approach_touch_speed_m_s: the guarded approach slows to this where the open fingers may meet the
            object: from `approach_touch_zone_m` before their tips reach the nearest face of its box [m/s].
            A touch is only stopped after it happened, and what it costs grows with the speed: in the
            simulator, fingers driven into a rigid table top and stopped at the first 40 N step press
            190 N (over 10 ms) at 0.1 m/s, 127 N at 0.07 and 96 N at 0.05, against the 150 N limit.
        approach_touch_zone_m: see `approach_touch_speed_m_s`: the fitted box's faces are ~1 cm off the
            object's and a part it left out reaches further [m].
        approach_touch_tolerance_m: a touch this close to the grasp pose is the grasp arriving, not an
            obstacle: the jaws close there, the pads that much shallower than planned (they are planned
            `pad_depth_margin_m` deep to spare) [m].
        grasp: `GraspConfig` of the planner.
    """

    max_estimates: int = 3
    grasps_per_estimate: int = 3
    camera_retries: int = 3
    observe_frames: int = 1
    timeout_s: float = 300.0
    joint_speed_rad_s: float = 1.0
    joint_accel_rad_s2: float = 2.0
    linear_speed_m_s: float = 0.2
    linear_accel_m_s2: float = 1.0
    grip_force_n: float = 60.0
    min_jaw_width_m: float = 0.004
    moved_min_m: float = 0.035
    max_scene_points: int = 40000
    reobserve: bool = True
    open_margin_m: float = 0.01
    candidates: int = 4
    candidate_ratio: float = 0.9
    candidate_order: str = "top_first"
    candidate_max_size_ratio: float | None = None
    max_objects: int = 12
    lift_clearance_m: float = 0.03
    max_lift_m: float = 0.35
    pad_depth_margin_m: float = 0.01
    max_object_height_m: float | None = None
    wrist_look_m: float = 0.15
    wrist_max_shift_m: float = 0.10
    self_filter_margin_m: float | None = 0.03
    wrong_object_margin: float = 0.3
    retry_wrong_object: bool = True
    approach_contact_force_n: float | None = 40.0
    approach_touch_speed_m_s: float = 0.05
    approach_touch_zone_m: float = 0.03
    approach_touch_tolerance_m: float = 0.005
    grasp: GraspConfig | None = None

    def __post_init__(self) -> None:
        ints = (
            "max_estimates",
            "grasps_per_estimate",
            "camera_retries",
            "observe_frames",
            "max_scene_points",
            "candidates",
            "max_objects",
        )
        for name in ints:
            if int(getattr(self, name)) < 1:
                raise InvalidInputError(f"PickConfig.{name} must be >= 1, got {getattr(self, name)}")
        floats = (
            "timeout_s",
            "joint_speed_rad_s",
            "joint_accel_rad_s2",
            "linear_speed_m_s",
            "linear_accel_m_s2",
            "grip_force_n",
            "moved_min_m",
            "open_margin_m",
            "candidate_ratio",
            "lift_clearance_m",
            "max_lift_m",
            "pad_depth_margin_m",
            "wrist_look_m",
            "wrist_max_shift_m",
            "approach_touch_speed_m_s",
            "approach_touch_zone_m",
            "approach_touch_tolerance_m",
        )
        for name in floats:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"PickConfig.{name} must be finite and > 0, got {v}")
        if not 0.0 < float(self.wrong_object_margin) < 1.0:  # a difference of probabilities
            raise InvalidInputError(
                f"PickConfig.wrong_object_margin must be in (0, 1), got {self.wrong_object_margin}"
            )
        r = self.candidate_max_size_ratio
        if r is not None and not (math.isfinite(float(r)) and float(r) >= 1.0):
            raise InvalidInputError(f"PickConfig.candidate_max_size_ratio must be None or >= 1, got {r}")
        if self.candidate_order not in CANDIDATE_ORDERS:
            raise InvalidInputError(
                f"PickConfig.candidate_order must be one of {', '.join(CANDIDATE_ORDERS)}, "
                f"got {self.candidate_order!r}"
            )
        m = self.self_filter_margin_m
        if m is not None and not (math.isfinite(float(m)) and float(m) >= 0):
            raise InvalidInputError(f"PickConfig.self_filter_margin_m must be None or >= 0 m, got {m}")
        f = self.approach_contact_force_n
        if f is not None and not (math.isfinite(float(f)) and float(f) > 0):
            raise InvalidInputError(f"PickConfig.approach_contact_force_n must be None or > 0 N, got {f}")
        h = self.max_object_height_m
        if h is not None and not (math.isfinite(float(h)) and float(h) > 0):
            raise InvalidInputError(f"PickConfig.max_object_height_m must be None or > 0 m, got {h}")
