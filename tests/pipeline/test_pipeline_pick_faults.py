"""PickAndPlace on fakes: each fault ends with its typed reason, the happy path succeeds, nothing raises.

The estimator here is an oracle stub (named so): it returns a fixed box, so the tests exercise the loop's
control flow and reasons, not perception (the sim episode test does that end to end).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from prompose_grasp.errors import (
    CameraError,
    InvalidInputError,
    ObjectNotFoundError,
    UnreachableError,
    UnsafeCommandError,
)
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import invert_T, make_T
from prompose_grasp.grasp import ParallelJawGeometry, PlaceTarget
from prompose_grasp.grasp.refine import lines_continuous
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.outcome import REASONS, STAGES, PickOutcome
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.pipeline.wrist_look import wrist_mount
from prompose_grasp.robot import FakeArm, FakeGripper, RGBDFrame, load_robot
from prompose_grasp.robot.interfaces import LinearCommand

JAW = ParallelJawGeometry()
ROBOT = load_robot("ur5e", tcp_offset=JAW.T_flange_tcp)
R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
# A camera 1 m above the table (base z = 0), looking straight down.
T_BASE_CAM = make_T(np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]), [-0.5, 0.0, 1.0])
K = CameraIntrinsics(fx=300.0, fy=300.0, cx=79.5, cy=59.5, width=160, height=120)
PICK = Command("pick up the box", "pick", "the box", False, None, "", 1.0, 0.0)


class Camera:
    """Frames of a flat table 1 m below; `fail` captures raise CameraError first (dropped frames); the first
    `holes` captures have no depth reading in the image centre (where the object stands)."""

    def __init__(self, fail: int = 0, T_base_cam=T_BASE_CAM, holes: int = 0):
        self.fail = fail
        self.T_base_cam = T_base_cam
        self.holes = holes
        self.calls = 0

    def capture(self) -> RGBDFrame:
        self.calls += 1
        if self.calls <= self.fail:
            raise CameraError("frame dropped")
        depth = np.full((K.height, K.width), 1.0, dtype=np.float32)
        if self.calls - self.fail <= self.holes:
            depth[:, 40:120] = 0.0  # no reading over the object (base x -0.5 +- 0.13 m at 1 m)
        rgb = np.zeros((K.height, K.width, 3), dtype=np.uint8)
        return RGBDFrame(rgb, depth, K, float(self.calls), self.T_base_cam)


class OracleEstimator:
    """Returns a box at `t_base` (base frame) in the camera frame of each frame; or raises not-found."""

    def __init__(self, t_base=(-0.5, 0.15, 0.03), found: bool = True, size=(0.05, 0.06, 0.06)):
        self.t_base = np.asarray(t_base, dtype=np.float64)
        self.found = found
        self.size = size
        self.calls = 0

    def estimate(self, frame, prompt):
        self.calls += 1
        if not self.found:
            raise ObjectNotFoundError(f"no object matches {prompt!r}")
        x_cam = self.t_base[0] - T_BASE_CAM[0, 3]  # the camera looks straight down from 1 m
        u = int(np.clip(K.cx + K.fx * x_cam / T_BASE_CAM[2, 3], 0, K.width - 1))
        if not frame.depth_m[int(K.cy), u] > 0:  # as the estimator: no depth points on the object
            raise ObjectNotFoundError(f"the mask of {prompt!r} holds no valid depth points")
        T_cam_base = invert_T(frame.T_base_cam)
        pose = Pose9D(R_UP, self.t_base, self.size).transformed(T_cam_base)
        mesh = trimesh.creation.box(extents=pose.size)
        mesh.apply_transform(pose.to_matrix())
        n_cam = T_cam_base[:3, :3] @ np.array([0.0, 0.0, 1.0])
        plane = SimpleNamespace(normal_cam=n_cam, offset_m=-float(n_cam @ T_cam_base[:3, 3]))
        prior = SimpleNamespace(name="box", symmetry="box")
        return SimpleNamespace(pose=pose, prior=prior, mesh_cam=mesh, support_plane=plane)


class RecordingArm(FakeArm):
    """FakeArm that records the commands its validator refused (the loop must never send one)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.refused: list[str] = []

    def _record(self, fn, *args):
        try:
            return fn(*args)
        except (UnsafeCommandError, UnreachableError) as exc:
            self.refused.append(str(exc))
            raise

    def move_joints(self, q, speed, accel):
        return self._record(super().move_joints, q, speed, accel)

    def move_linear(self, T_base_tcp, speed, accel):
        return self._record(super().move_linear, T_base_tcp, speed, accel)

    def follow(self, trajectory):
        return self._record(super().follow, trajectory)


def _run(
    camera=None, estimator=None, object_width_m=0.05, config=None, command=PICK
) -> tuple[PickOutcome, list]:
    events: list = []
    cfg = config or PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=2)
    with RecordingArm(ROBOT) as arm, FakeGripper(object_width_m=object_width_m) as gripper:
        pnp = PickAndPlace(
            arm,
            gripper,
            camera or Camera(),
            estimator or OracleEstimator(),
            ROBOT,
            "parallel_jaw",
            config=cfg,
            on_event=events.append,
        )
        outcome = pnp.run(command)
    # Nothing the validator rejects is ever sent: every command the loop gave the arm was accepted.
    assert arm.refused == [], arm.refused
    return outcome, events


def test_happy_path_succeeds_with_events_and_timings():
    outcome, events = _run()
    assert outcome.success and outcome.reason == "success", outcome.message
    assert outcome.grasp is not None and len(outcome.attempts) == 1
    assert outcome.attempts[0].gripper_width_m == pytest.approx(0.05)
    assert events[0].stage == "parse" and events[-1].stage == "done"
    assert all(e.stage in STAGES for e in events)
    assert set(outcome.timings_s) >= {"observe", "estimate", "plan", "execute", "verify", "total"}
    assert outcome.timings_s["total"] >= outcome.timings_s["plan"] > 0


def test_dropped_frames_are_retried():
    outcome, _ = _run(camera=Camera(fail=2))
    assert outcome.success, outcome.message


def test_transient_depth_holes_over_the_target_are_observed_again():
    outcome, _ = _run(camera=Camera(holes=2))  # two frames without depth on the object, then a good one
    assert outcome.success, outcome.message


def test_persistent_depth_holes_over_the_target_are_not_found():
    outcome, _ = _run(camera=Camera(holes=10**6))
    assert outcome.reason == "not_found" and "no valid depth" in outcome.message
    assert outcome.attempts == ()


def test_camera_that_always_raises_is_camera_failed():
    outcome, _ = _run(camera=Camera(fail=10**6))
    assert outcome.reason == "camera_failed" and not outcome.success
    assert outcome.estimates == () and outcome.attempts == ()


def test_uncalibrated_camera_is_camera_failed():
    outcome, _ = _run(camera=Camera(T_base_cam=None))
    assert outcome.reason == "camera_failed"


def test_object_not_found():
    outcome, _ = _run(estimator=OracleEstimator(found=False))
    assert outcome.reason == "not_found"


def test_unreachable_object_is_ik_failed():
    outcome, _ = _run(estimator=OracleEstimator(t_base=(1.4, 0.0, 0.03)))  # 1.4 m: beyond a UR5e's 0.85 m
    assert outcome.reason == "ik_failed", outcome.message


def test_empty_grasp_is_slipped_after_every_retry():
    outcome, _ = _run(object_width_m=None)  # the jaws close on nothing
    assert outcome.reason == "slipped"
    assert len(outcome.attempts) == 2 and all(a.result == "slipped" for a in outcome.attempts)
    assert len(outcome.estimates) == 2  # a slip starts a new round with a fresh estimate


def test_reobservation_of_an_unmoved_object_is_slipped():
    # The gripper reports a hold, but the camera still sees the object where it stood.
    outcome, _ = _run(config=PickConfig(reobserve=True, max_estimates=1, grasps_per_estimate=1))
    assert outcome.reason == "slipped" and "still where it stood" in outcome.message


class SeenStretchedInTheHand(OracleEstimator):
    """After the first estimate, the object is seen lifted in the hand but its box reaches down to the table
    (partly hidden by the gripper): top 56 mm higher, centre only 28 mm higher (as seed 247's bottle)."""

    def estimate(self, frame, prompt):
        if self.calls == 1:
            self.t_base = self.t_base + np.array([0.0, 0.0, 0.028])
            self.size = (self.size[0], self.size[1] + 0.056, self.size[2])  # object +y is up (R_UP)
        return super().estimate(frame, prompt)


def test_reobservation_counts_a_risen_top_as_lifted():
    # The centre moved 28 mm (< moved_min_m 35 mm) but the top rose 56 mm: the object was lifted.
    cfg = PickConfig(reobserve=True, max_estimates=1, grasps_per_estimate=1)
    outcome, _ = _run(estimator=SeenStretchedInTheHand(), config=cfg)
    assert outcome.success, outcome.message


def test_timeout():
    outcome, _ = _run(config=PickConfig(timeout_s=1e-9, reobserve=False))
    assert outcome.reason == "timeout"


def test_place_without_a_configured_target_is_not_found():
    cmd = Command("put the box in the bin", "place", "the box", False, "bin", "the bin", 1.0, 1.0)
    outcome, _ = _run(command=cmd)
    assert outcome.reason == "not_found" and "bin" in outcome.message


def test_unparsable_command_is_not_understood_and_says_so():
    outcome, _ = _run(command="sing the box a song")
    assert outcome.reason == "not_understood" and not outcome.success
    assert "could not understand" in outcome.message and "pick up the red mug" in outcome.message
    assert outcome.attempts == () and outcome.estimates == ()


def test_a_thin_wall_between_the_jaws_is_a_hold_and_the_same_stop_on_a_box_is_not():
    # A 4 mm plate (a cup's wall seen as a box): the jaws stop at 3 mm (the pads squeeze it); that is below
    # the 4 mm `min_jaw_width_m` but above half the planned 4 mm width: held.
    plate = OracleEstimator(size=(0.004, 0.06, 0.06))
    outcome, _ = _run(estimator=plate, object_width_m=0.003)
    assert outcome.success, outcome.message
    assert outcome.attempts[-1].gripper_width_m == pytest.approx(0.003)
    # The same 3 mm stop on the 5 cm box is nothing held (fingers closed past where the box should be).
    outcome, _ = _run(object_width_m=0.003)
    assert outcome.reason == "slipped" and "3.0 mm" in outcome.message


class TwoCandidates(OracleEstimator):
    """Two candidates for the prompt: the best match (score 0.84, 6 cm tall) and, 90 % as good, a taller
    object (score 0.78, 10 cm tall: another thing behind it)."""

    def estimate_all(self, frame, prompt, max_objects=None, min_score_ratio=0.0):
        best = self.estimate(frame, prompt)
        best.score = 0.84
        other = OracleEstimator(t_base=(-0.45, -0.15, 0.05), size=(0.05, 0.10, 0.06)).estimate(frame, prompt)
        other.score = 0.78
        return [best, other]


@pytest.mark.parametrize(("order", "y_expected"), [("score", 0.15), ("top_first", -0.15)])
def test_candidate_order_picks_the_best_match_or_the_highest_top(order, y_expected):
    cfg = PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=1, candidate_order=order)
    outcome, _ = _run(estimator=TwoCandidates(), config=cfg)
    assert outcome.success, outcome.message
    # The grasp closes on the chosen candidate: its tcp within the box's 3 cm half width of that centre.
    assert outcome.grasp.T_base_tcp[1, 3] == pytest.approx(y_expected, abs=0.03)


class TallOther(OracleEstimator):
    """The best match (score 0.84, a 6 cm box) and, 90 % as good, a box 50 cm tall (another thing)."""

    def estimate_all(self, frame, prompt, max_objects=None, min_score_ratio=0.0):
        best = self.estimate(frame, prompt)
        best.score = 0.84
        other = OracleEstimator(t_base=(-0.45, -0.15, 0.25), size=(0.05, 0.5, 0.06)).estimate(frame, prompt)
        other.score = 0.78
        return [best, other]


def test_a_candidate_unlike_the_best_in_size_comes_after_the_alike_ones():
    # Highest top first would try the 50 cm box (top at 0.5 m); with a size ratio of 2 it is unlike the 6 cm
    # best match (8x taller) and goes last: the grasp closes on the best match (within its 3 cm half width).
    cfg = PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=1, candidate_max_size_ratio=2.0)
    outcome, _ = _run(estimator=TallOther(), config=cfg)
    assert outcome.success, outcome.message
    assert outcome.grasp.T_base_tcp[1, 3] == pytest.approx(0.15, abs=0.03)
    with pytest.raises(InvalidInputError, match="candidate_max_size_ratio"):
        PickConfig(candidate_max_size_ratio=0.5)


def test_unknown_candidate_order_is_refused_with_the_choices():
    with pytest.raises(InvalidInputError, match="top_first, score"):
        PickConfig(candidate_order="tallest")


class _JumpyRobot:
    """The UR5e whose IK adds 0.5 rad to wrist 1 below z = 0.05 m (a branch flip on the way down)."""

    def ik(self, T, q_seed=None, frame="tcp"):
        result = ROBOT.ik(T, q_seed=q_seed, frame=frame)
        if result.success and T[2, 3] < 0.05:
            q = np.array(result.q)
            q[3] += 0.5
            return SimpleNamespace(success=True, q=q)
        return result


def test_a_grasp_whose_approach_line_flips_a_wrist_is_not_continuous():
    outcome, _ = _run()
    grasp = outcome.grasp  # a top-down grasp on the box (tcp at z ~ 0.03 m), approached from 10 cm above
    assert lines_continuous(ROBOT, grasp)
    # The same lines with IK that jumps 0.5 rad (> the 0.2 rad the check allows between 5 mm steps) below
    # 5 cm: the approach crosses z = 0.05 m, so it is refused.
    assert not lines_continuous(_JumpyRobot(), grasp)


def test_reasons_are_the_issue_list_plus_not_understood_ambiguous_wrong_object_and_device_faults():
    assert REASONS == (
        "success",
        "not_found",
        "no_feasible_grasp",
        "ik_failed",
        "slipped",
        "collision",
        "timeout",
        "camera_failed",
        "not_understood",
        "ambiguous",
        "wrong_object",
        "protective_stop",
        "emergency_stop",
        "connection_lost",
        "motion_failed",
        "gripper_failed",
    )
    for reason in REASONS:  # every reason makes an outcome and its JSON summary
        assert PickOutcome(reason, "m").to_dict()["reason"] == reason


def test_aim_camera_puts_the_target_on_the_optical_axis():
    from scipy.spatial.transform import Rotation

    from prompose_grasp.pipeline.wrist_look import aim_camera

    rng = np.random.default_rng(3)
    for _ in range(20):
        T_tcp = make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.5, 0.5, 3))
        # A camera beside the tool (as the wrist camera: 7 cm off the axis), turned a little.
        T_tcp_cam = make_T(Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix(), [0.0, 0.07, -0.12])
        point = rng.uniform(-0.5, 0.5, 3)
        T = aim_camera(T_tcp, T_tcp_cam, point)
        np.testing.assert_array_equal(T[:3, :3], T_tcp[:3, :3])  # the orientation is kept
        cam = T @ T_tcp_cam
        d = point - cam[:3, 3]
        # The point lies on the camera's +z axis (float64 round off on ~1 m vectors), as far ahead as before.
        assert np.linalg.norm(d - (d @ cam[:3, 2]) * cam[:3, 2]) < 1e-12
        before = T_tcp @ T_tcp_cam
        assert d @ cam[:3, 2] == pytest.approx((point - before[:3, 3]) @ before[:3, 2], abs=1e-12)


class WristCamera(Camera):
    """A camera on the flange at `T_flange_cam`: its frames carry T_base_cam = fk(q) T_flange_cam."""

    def __init__(self, arm, T_flange_cam, fail: int = 0):
        super().__init__(fail=fail)
        self.arm = arm
        self.T_flange_cam = T_flange_cam

    def capture(self) -> RGBDFrame:
        self.T_base_cam = ROBOT.fk(self.arm.joint_positions()) @ self.T_flange_cam
        return super().capture()


@pytest.mark.parametrize("fail", [0, 1])
def test_the_wrist_camera_mount_is_learned_from_one_capture(fail):
    T_flange_cam = make_T(np.eye(3), [0.0, 0.07, 0.03])
    with FakeArm(ROBOT) as arm, FakeGripper(object_width_m=0.05) as gripper:
        wrist = WristCamera(arm, T_flange_cam, fail=fail)
        pnp = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", wrist_camera=wrist
        )
        if fail:  # a dropped frame: not learned now, no crash
            assert wrist_mount(pnp.loop) is None
        # Learned from the frame's hand-eye pose and the joints (exact up to float64 FK round off) ...
        np.testing.assert_allclose(wrist_mount(pnp.loop), T_flange_cam, atol=1e-12)
        calls = wrist.calls
        wrist_mount(pnp.loop)
        assert wrist.calls == calls  # ... once


class RanksFlip(OracleEstimator):
    """Two candidates whose ranking flips after the first frame: A (y = +0.15) is the best match at first,
    then B (y = -0.15) scores best and A falls under the 90 % candidate ratio (a noisy frame)."""

    def estimate_all(self, frame, prompt, max_objects=None, min_score_ratio=0.0):
        a = OracleEstimator(t_base=(-0.5, 0.15, 0.03)).estimate(frame, prompt)
        b = OracleEstimator(t_base=(-0.45, -0.15, 0.03)).estimate(frame, prompt)
        self.calls += 1
        a.score, b.score = (0.84, 0.5) if self.calls == 1 else (0.5, 0.84)
        ests = sorted([a, b], key=lambda e: -e.score)
        return [e for e in ests if e.score >= min_score_ratio * ests[0].score]


def test_a_retry_tries_the_object_where_it_stood_first():
    # The jaws close on nothing: round 1 on A slips; round 2 sees B ranked first, A under the ratio, yet tries
    # A again (objects do not move by themselves; a noisy frame re-ranked them).
    cfg = PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=1, candidate_order="score")
    outcome, _ = _run(estimator=RanksFlip(), object_width_m=None, config=cfg)
    assert outcome.reason == "slipped" and len(outcome.attempts) == 2
    for attempt in outcome.attempts:  # each grasp closes on A: its tcp within A's 3 cm half width
        assert attempt.grasp.T_base_tcp[1, 3] == pytest.approx(0.15, abs=0.03)


class TouchingArm(RecordingArm):
    """A fake arm that measures the force at its tool: its first `touches` guarded lines at the touch speed
    (`PickConfig().approach_touch_speed_m_s`: where the fingers pass the object) stop on contact `short_m`
    before their end (a part of the object the plan did not know of); `guarded` lists each guarded line as
    (speed, max_force_n, reached)."""

    senses_contact = True

    def __init__(self, *args, touches: int = 1, short_m: float = 0.01, **kwargs):
        super().__init__(*args, **kwargs)
        self.touches, self.short_m = touches, short_m
        self.guarded: list[tuple[float, float, bool]] = []

    def move_linear_until_contact(self, T_base_tcp, speed, accel, max_force_n):
        T = np.array(T_base_tcp, dtype=np.float64)
        if self.touches > 0 and speed == PickConfig().approach_touch_speed_m_s:
            self.touches -= 1
            T[:3, 3] -= self.short_m * T[:3, 2]  # stops short, back along the approach (tcp +z)
            self.move_linear(T, speed, accel)
            self.guarded.append((speed, max_force_n, False))
            return False
        self.move_linear(T, speed, accel)
        self.guarded.append((speed, max_force_n, True))
        return True


def _run_touching(touches: int, config: PickConfig) -> tuple[PickOutcome, TouchingArm]:
    with TouchingArm(ROBOT, touches=touches) as arm, FakeGripper(object_width_m=0.05) as gripper:
        outcome = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=config
        ).run(PICK)
    assert arm.refused == [], arm.refused
    return outcome, arm


def test_a_touch_on_the_approach_backs_off_and_the_next_grasp_is_tried():
    cfg = PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=2)
    outcome, arm = _run_touching(1, cfg)
    assert outcome.success, outcome.message
    first, second = outcome.attempts
    assert first.result == "collision" and "touched something 10 mm before the grasp pose" in first.message
    assert "40 N" in first.message and second.result == "success"
    # The touch was on the slow leg, at the touch speed and the configured force; after it the arm backed
    # off to the touched grasp's pre-grasp (the next command is a line there, not the next grasp's moves).
    speed = cfg.approach_touch_speed_m_s
    assert arm.guarded[0] == (cfg.linear_speed_m_s, 40.0, True)  # the fast leg, down to the touch zone
    assert [g for g in arm.guarded if not g[2]] == [(speed, 40.0, False)]
    i = next(k for k, c in enumerate(arm.sent) if isinstance(c, LinearCommand) and c.speed_m_s == speed)
    back = arm.sent[i + 1]
    assert isinstance(back, LinearCommand)
    np.testing.assert_allclose(back.T_base_tcp, first.grasp.T_base_pregrasp, atol=1e-9)  # exactly there
    # Every later approach is guarded too: its last leg at the touch speed, reached.
    assert arm.guarded[-1] == (cfg.approach_touch_speed_m_s, 40.0, True)


def test_touches_on_every_grasp_end_the_run_as_a_collision_and_none_is_unguarded():
    outcome, _ = _run_touching(10**6, PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=2))
    assert outcome.reason == "collision" and not outcome.success
    assert [a.result for a in outcome.attempts] == ["collision", "collision"]


def test_the_guard_can_be_switched_off_and_is_validated():
    outcome, arm = _run_touching(10**6, PickConfig(reobserve=False, approach_contact_force_n=None))
    assert outcome.success and arm.guarded == []  # a plain move_linear approach: nothing guarded
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="approach_contact_force_n"):
            PickConfig(approach_contact_force_n=bad)


def test_the_touch_zone_starts_where_the_fingertips_reach_the_box_top():
    from prompose_grasp.grasp.types import ObjectModel
    from prompose_grasp.pipeline.execute import touch_zone_m

    # Straight down (tcp +z = base -z) onto a box whose top is at z = 0.06 m; the tcp ends at z = 0.04 with
    # the tips 0.015 m below it (z = 0.025): they cross the top 0.035 m before the end, plus the margin.
    T = make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.04])
    box = ObjectModel("box", Pose9D(R_UP, [0.0, 0.0, 0.03], [0.05, 0.06, 0.06]))
    assert touch_zone_m(T, box, 0.015, 0.03) == pytest.approx(0.065, abs=1e-12)
    assert touch_zone_m(T, None, 0.015, 0.03) == 0.03  # no target: the margin alone
    # A grasp whose tips stop above the box (they never reach it) still slows for the margin.
    assert touch_zone_m(make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.2]), box, 0.015, 0.03) == 0.03


def test_the_wrist_target_keeps_what_the_first_view_saw_of_the_object():
    from prompose_grasp.grasp.types import ObjectModel
    from prompose_grasp.pipeline.wrist_look import with_first_view

    pose = Pose9D(R_UP, [-0.5, 0.1, 0.03], [0.05, 0.06, 0.06])
    tops = np.array([[-0.5, 0.1, 0.06], [-0.49, 0.1, 0.06]])  # the wrist, from above
    side = np.array([[-0.46, 0.1, 0.03]])  # the fixed camera, an ear on the side
    wrist = ObjectModel("target", pose, surface_points=tops)
    joined = with_first_view(wrist, ObjectModel("target", pose, surface_points=side))
    np.testing.assert_array_equal(joined.surface_points, np.vstack([tops, side]))  # both views, in order
    assert joined.pose is wrist.pose  # the wrist's closer estimate stays the box
    # Nothing to join: the wrist's target as it is; a wrist view without a seen surface takes the first's.
    assert with_first_view(wrist, ObjectModel("target", pose)) is wrist
    bare = with_first_view(ObjectModel("target", pose), ObjectModel("target", pose, surface_points=side))
    np.testing.assert_array_equal(bare.surface_points, side)


def test_a_touch_within_the_tolerance_of_the_grasp_pose_is_the_grasp_arriving():
    cfg = PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=1)
    with TouchingArm(ROBOT, touches=1, short_m=0.004) as arm, FakeGripper(object_width_m=0.05) as gripper:
        outcome = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=cfg
        ).run(PICK)
    # 4 mm short (tolerance 5 mm): the jaws closed there, the first grasp held, nothing backed off
    assert outcome.success and [a.result for a in outcome.attempts] == ["success"], outcome.message
    assert arm.guarded[-1][2] is False and arm.refused == []


def test_the_approach_of_a_place_command_is_guarded_too():
    table = PlaceTarget("surface", make_T(np.eye(3), [-0.3, 0.4, 0.0]), [0.12, 0.12])
    place = Command("put the box on the table", "place", "the box", False, "table", "the table", 1.0, 1.0)
    cfg = PickConfig(reobserve=False, max_estimates=1, grasps_per_estimate=2)
    with TouchingArm(ROBOT, touches=1) as arm, FakeGripper(object_width_m=0.05) as gripper:
        outcome = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=cfg,
            place_targets={"table": table},
        ).run(place)  # fmt: skip
    # the first grasp's approach (a straight line inside the planned pick-and-place) touched and backed off;
    # the second was placed
    assert [a.result for a in outcome.attempts] == ["collision", "success"], outcome.message
    assert outcome.success and outcome.place is not None
    assert arm.refused == []
    assert [g for g in arm.guarded if not g[2]] == [(cfg.approach_touch_speed_m_s, 40.0, False)]
