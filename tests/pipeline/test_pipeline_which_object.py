"""PickAndPlace on fakes: which object. Several that fit equally end "ambiguous" before anything moves (a
plural command or a stack takes any); none that fits is "not_found"; a wrong object found in the hand after
the lift is put back ("wrong_object"), or the better candidate is tried once.

The estimators are oracle stubs over a known little world (boxes on the table under a top-down camera): the
tests exercise the loop's control flow, not perception.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from test_pipeline_pick_faults import PICK, ROBOT, Camera, K, OracleEstimator, RecordingArm

from prompose_grasp.errors import AmbiguousObjectError, InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp import ObjectModel, PlaceTarget, Plane
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.observe import Observation
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.pipeline.wrong_object import revealed, rose_since
from prompose_grasp.robot import FakeGripper, RGBDFrame
from prompose_grasp.robot.fake import HOME_Q
from prompose_grasp.robot.interfaces import LinearCommand

#: A tabletop of different things (the best match first): the loop judges ambiguity and the margin.
BY_SCORE = dict(reobserve=False, max_estimates=2, grasps_per_estimate=1, candidate_order="score")


def _box(t_base, size, colour, contenders=-1, probability=float("nan"), score=0.8):
    """An oracle estimate of an upright box (base frame), with what a grounder would have measured."""

    def estimate(frame, prompt):
        est = OracleEstimator(t_base=t_base, size=size).estimate(frame, prompt)
        est.score, est.probability, est.contenders = score, probability, contenders
        est.attributes = SimpleNamespace(
            colour_name=colour, description=f"a small {colour} box-shaped object"
        )
        return est

    return estimate


class Contenders(OracleEstimator):
    """A red box 17 cm tall left of a blue one 10 cm tall (in the camera's view), both fitting equally:
    `contenders` of the best estimate is `n` (2: ambiguous, 0: none fits, -1: not judged)."""

    def __init__(self, n: int = 2):
        super().__init__()
        self.n = n
        self.red = _box([-0.6, 0.0, 0.085], (0.05, 0.17, 0.06), "red", n, 0.45, 0.84)
        self.blue = _box([-0.4, 0.0, 0.05], (0.05, 0.10, 0.06), "blue", n, 0.44, 0.83)

    def estimate_all(self, frame, prompt, max_objects=None, min_score_ratio=0.0):
        self.calls += 1
        return [self.red(frame, prompt), self.blue(frame, prompt)]


class RefusesToChoose(Contenders):
    """`estimate` raises `AmbiguousObjectError` with both estimates (as `ProMPose.estimate` does); the loop
    calls it with `PickConfig.candidates` 1."""

    def estimate(self, frame, prompt):
        self.calls += 1
        raise AmbiguousObjectError(prompt, [self.red(frame, prompt), self.blue(frame, prompt)])


class SpyGripper(FakeGripper):
    """A FakeGripper that logs each open and close with the number of commands the arm had been sent."""

    def __init__(self, arm):
        super().__init__(object_width_m=0.05)
        self.arm = arm
        self.log: list[tuple[str, int]] = []

    def open(self):
        super().open()
        self.log.append(("open", len(self.arm.sent)))

    def close(self, force):
        self.log.append(("close", len(self.arm.sent)))
        return super().close(force)


def _cell(estimator, config, command=PICK, world=None, places=None):
    """Run `command` (on a `World` with its camera and estimator, when `world` makes one from the arm and
    the gripper); the outcome, the arm (its `sent` commands) and the gripper (its `log`)."""
    with RecordingArm(ROBOT) as arm:
        with SpyGripper(arm) as gripper:
            camera = Camera()
            if world is not None:
                w = world(arm, gripper)
                camera, estimator = WorldCamera(w), WorldEstimator(w)
            pnp = PickAndPlace(
                arm, gripper, camera, estimator, ROBOT, "parallel_jaw", place_targets=places, config=config
            )
            outcome = pnp.run(command)
    assert arm.refused == [], arm.refused  # nothing the validator refuses is ever sent
    return outcome, arm, gripper


EXPECTED = (
    "2 objects fit 'the box': the red box on the left, 17 cm tall; the blue box on the right, 10 cm tall. "
    'Say which one (e.g. "the red box").'
)


def test_two_equally_fitting_objects_are_ambiguous_and_nothing_moves():
    estimator = Contenders(2)
    outcome, arm, gripper = _cell(estimator, PickConfig(**BY_SCORE))
    assert outcome.reason == "ambiguous" and outcome.message == EXPECTED
    assert arm.sent == [] and outcome.attempts == () and outcome.grasp is None  # the arm never moved
    assert not any(what == "close" for what, _ in gripper.log)  # and the jaws never closed
    assert estimator.calls == 1  # an answer, not retried like "not_found"
    # The outcome carries the contenders' estimates, best first, with the frame they were seen in.
    assert [e.attributes.colour_name for e in outcome.estimates] == ["red", "blue"]
    assert len(outcome.T_base_cams) == 2 and outcome.T_base_cams[0].shape == (4, 4)


def test_an_estimator_that_refuses_to_choose_is_ambiguous_too():
    # `estimate` raising AmbiguousObjectError (as ProMPose.estimate does), one candidate asked for.
    outcome, arm, _ = _cell(RefusesToChoose(), PickConfig(**BY_SCORE, candidates=1))
    assert outcome.reason == "ambiguous" and outcome.message == EXPECTED
    assert arm.sent == []


def test_a_plural_command_or_a_stack_takes_any_of_the_equal_ones():
    plural = Command("pick up the boxes", "pick", "the boxes", True, None, "", 1.0, 0.0)
    outcome, _, _ = _cell(Contenders(2), PickConfig(**{**BY_SCORE, "max_objects": 1}), command=plural)
    assert outcome.success and outcome.objects_done == 1, outcome.message
    stack = PickConfig(**{**BY_SCORE, "candidate_order": "top_first"})
    outcome, _, _ = _cell(Contenders(2), stack)
    assert outcome.success, outcome.message
    # The highest top first: the 17 cm red box (its centre at base x -0.6; the grasp within its 2.5 cm half
    # width along x).
    assert outcome.grasp.T_base_tcp[0, 3] == pytest.approx(-0.6, abs=0.025)


def test_none_fitting_the_words_is_not_found_and_contenders_not_judged_change_nothing():
    estimator = Contenders(0)
    outcome, arm, _ = _cell(estimator, PickConfig(**BY_SCORE))
    assert outcome.reason == "not_found" and "fits the words" in outcome.message
    # judged on the candidates seen, not an empty frame: not retried (fresh frames asked until noise makes
    # one clear would turn the refusal into a guess)
    assert arm.sent == [] and estimator.calls == 1
    outcome, _, _ = _cell(Contenders(-1), PickConfig(**BY_SCORE))  # -1: today's loop, the best match
    assert outcome.success, outcome.message
    assert outcome.grasp.T_base_tcp[0, 3] == pytest.approx(-0.6, abs=0.025)


def test_like_things_that_share_the_probability_are_found_when_any_will_do():
    # Two boxes at 0.45 and 0.44: neither alone likelier than not the one named (contenders 0), but one of
    # them is meant with 0.89. A stack of like things takes the top one; a command for one object is refused.
    stack = PickConfig(**{**BY_SCORE, "candidate_order": "top_first"})
    outcome, _, _ = _cell(Contenders(0), stack)
    assert outcome.success, outcome.message
    outcome, _, _ = _cell(Contenders(0), PickConfig(**BY_SCORE))
    assert outcome.reason == "not_found"
    # 0.3 between them: "none" is likelier than any of them, even where any will do
    weak = Contenders(0)
    weak.red = _box([-0.6, 0.0, 0.085], (0.05, 0.17, 0.06), "red", 0, 0.2, 0.84)
    weak.blue = _box([-0.4, 0.0, 0.05], (0.05, 0.10, 0.06), "blue", 0, 0.1, 0.83)
    outcome, arm, _ = _cell(weak, stack)
    assert outcome.reason == "not_found" and arm.sent == []


# ------------------------------------------------------------------------------------------ wrong object
#: The world's two boxes (base frame) [m]: A, red, and B, blue, 6 cm cubes-ish on the table; the grounder
#: ranks A first (its score against B's).
HOME = {"A": np.array([-0.5, 0.15, 0.03]), "B": np.array([-0.45, -0.15, 0.03])}
SIZE = (0.05, 0.06, 0.06)
RGB = {"A": (200, 20, 20), "B": (20, 20, 200)}
COLOUR = {"A": "red", "B": "blue"}
SCORES = {"A": 0.84, "B": 0.80}


class World:
    """A and B (`HOME`) on the table 1 m under the top-down camera. The one whose place is under the tcp (3 cm
    across) is in the hand while the gripper holds: its centre is then at the tcp. With nothing held the
    grounder gives the probabilities `p_before` (A, B); with an object in the hand (a clearer view)
    `p_after`."""

    def __init__(
        self, arm, gripper, p_before=(0.5, 0.4), p_after=(0.1, 0.8), held_box_on_table=False, hanging=False
    ):
        self.arm, self.gripper = arm, gripper
        self.p_before, self.p_after = p_before, p_after
        self.held_box_on_table = held_box_on_table  # the held box's estimate still stands on the table
        # the held box hangs from the jaws tilted, 4 cm up, one edge of it still on the table
        self.hanging = hanging
        self.estimates: list = []

    def held(self) -> str | None:
        if not self.gripper.grasp_detected():
            return None
        tcp = ROBOT.fk_tcp(self.arm.joint_positions())[:3, 3]
        for name, home in HOME.items():
            if np.linalg.norm((tcp - home)[:2]) < 0.03:
                return name
        return None

    def centres(self) -> dict[str, np.ndarray]:
        held = self.held()
        tcp = ROBOT.fk_tcp(self.arm.joint_positions())[:3, 3]
        if self.hanging:
            return {n: (h + np.array([0.0, 0.0, 0.04]) if n == held else h) for n, h in HOME.items()}
        return {n: (tcp.copy() if n == held else h) for n, h in HOME.items()}

    def render(self, T_base_cam) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Depth, colour and each box's visible pixels (its top face) of the top-down camera."""
        v, u = np.mgrid[0 : K.height, 0 : K.width].astype(np.float64)
        depth = np.full((K.height, K.width), 1.0)
        rgb = np.full((K.height, K.width, 3), 90, dtype=np.uint8)  # a grey table
        owner = np.full((K.height, K.width), "", dtype=object)
        for name, t in self.centres().items():
            d = T_base_cam[2, 3] - (t[2] + SIZE[1] / 2)  # the top face's depth
            x = (u - K.cx) / K.fx * d + T_base_cam[0, 3]
            y = -(v - K.cy) / K.fy * d
            top = (np.abs(x - t[0]) <= SIZE[0] / 2) & (np.abs(y - t[1]) <= SIZE[2] / 2) & (d < depth)
            depth[top], rgb[top], owner[top] = d, RGB[name], name
            if self.hanging and name == self.held():
                rows, cols = np.nonzero(top)
                edge = cols == cols.min()  # its resting edge: 5 mm above the table
                depth[rows[edge], cols[edge]] = T_base_cam[2, 3] - 0.005
        return depth.astype(np.float32), rgb, {n: owner == n for n in HOME}


class WorldCamera(Camera):
    def __init__(self, world: World):
        super().__init__()
        self.world = world

    def capture(self) -> RGBDFrame:
        self.calls += 1
        depth, rgb, _ = self.world.render(self.T_base_cam)
        return RGBDFrame(rgb, depth, K, float(self.calls), self.T_base_cam)


class WorldEstimator(OracleEstimator):
    """Estimates of both boxes where the world has them (masks from the same rendering), best score first."""

    def __init__(self, world: World):
        super().__init__()
        self.world = world

    def estimate_all(self, frame, prompt, max_objects=None, min_score_ratio=0.0):
        _, _, masks = self.world.render(frame.T_base_cam)
        p = self.world.p_before if self.world.held() is None else self.world.p_after
        out = []
        for k, (name, t) in enumerate(self.world.centres().items()):
            if self.world.held_box_on_table and name == self.world.held():
                t = np.array([t[0], t[1], HOME[name][2]])  # an amodal box reaching down to the table
            est = _box(t, SIZE, COLOUR[name], 1, p[k], SCORES[name])(frame, prompt)
            est.mask, est.name = masks[name], name
            out.append(est)
        return sorted(out, key=lambda e: -e.score)


def _world_cell(
    command_prompt: str,
    p_before=(0.5, 0.4),
    p_after=(0.1, 0.8),
    command=None,
    places=None,
    held_box_on_table=False,
    hanging=False,
    **kwargs,
):
    """Pick `command_prompt` in a `World` (re-observing after the lift; no self filter: the fake camera
    does not see the robot, only the boxes, whose top faces the gripper's capsules would cover)."""
    config = PickConfig(**{**BY_SCORE, "reobserve": True, "self_filter_margin_m": None, **kwargs})
    command = command or Command(
        f"pick up {command_prompt}", "pick", command_prompt, False, None, "", 1.0, 0.0
    )
    outcome, arm, gripper = _cell(
        None,
        config,
        command,
        world=lambda arm, grip: World(arm, grip, p_before, p_after, held_box_on_table, hanging),
        places=places,
    )
    return outcome, arm, gripper, gripper.log


def _put_back_index(sent: list, grasp, log: list) -> int:
    """Where in `sent` the arm, after the jaws closed, went back down to the grasp pose in a straight line
    and then to the retreat (the put-back); -1 when it did not."""
    closed = next(n for what, n in log if what == "close")  # commands sent before the jaws closed
    for k in range(closed, len(sent) - 1):
        down, up = sent[k], sent[k + 1]
        if isinstance(down, LinearCommand) and isinstance(up, LinearCommand):
            # The poses as planned (the arm's validated copy of the command, float64 exact).
            if np.allclose(down.T_base_tcp, grasp.T_base_tcp) and np.allclose(
                up.T_base_tcp, grasp.T_base_retreat
            ):
                return k
    return -1


def test_a_wrong_object_in_the_hand_is_put_back_and_named():
    # After the lift A (in the hand) fits "the box" with p 0.1, B (standing) with 0.8: a lead of 0.7 over
    # the 0.3 margin. A goes back down the lift line, the jaws open, the arm retreats; the run ends.
    outcome, arm, _, log = _world_cell("the box", retry_wrong_object=False)
    assert outcome.reason == "wrong_object", outcome.message
    assert outcome.message.startswith("holding a small red box-shaped object, not 'the box' (p 0.10 against")
    assert "that is more likely the blue box on the right, 6 cm tall" in outcome.message
    assert outcome.message.endswith("put it back where it stood")
    assert [a.result for a in outcome.attempts] == ["wrong_object"]
    grasp = outcome.attempts[0].grasp
    assert grasp.T_base_tcp[1, 3] == pytest.approx(0.15, abs=0.03)  # it had closed on A (3 cm half width)
    k = _put_back_index(arm.sent, grasp, log)
    assert k > 0, "the put-back move was not sent"
    assert ("open", k + 1) in log  # opened at the grasp pose, before the retreat was sent
    assert log[-1][0] == "open"  # nothing is held at the end
    assert np.allclose(arm.sent[-1].q, HOME_Q)  # and the arm went back to where it started


def test_a_held_object_whose_box_reaches_down_to_the_table_is_still_judged():
    # Seen in the air and partly behind the jaws, a held object's amodal box can reach down to the table:
    # here A's estimate after the lift has its centre where A stood. Its seen points (its top face, in the
    # air under the tcp) are all far above the table, so it is the held object, and it is the wrong one.
    outcome, arm, _, log = _world_cell("the box", held_box_on_table=True, retry_wrong_object=False)
    assert outcome.reason == "wrong_object", outcome.message
    assert _put_back_index(arm.sent, outcome.attempts[0].grasp, log) > 0


def test_an_object_hanging_from_the_jaws_with_an_edge_on_the_table_is_not_picked():
    # The box (the right one) hangs tilted after the lift: its centre rose 4 cm of the 10 cm lift (more than
    # `moved_min_m`, so not "still where it stood"), and one edge of it rests on the table. Not a pick: the
    # jaws open and the attempt is "slipped", every time.
    outcome, _, _, log = _world_cell("the box", (0.5, 0.4), (0.8, 0.1), hanging=True)
    assert not outcome.success
    assert outcome.attempts and {a.result for a in outcome.attempts} == {"slipped"}, outcome.message
    assert all("hangs from the jaws" in a.message for a in outcome.attempts)
    assert "40 mm of the 100 mm lift" in outcome.attempts[0].message
    assert log[-1][0] == "open"
    # held in the air all the while (the same box lifted with the tcp), it is a pick
    outcome, _, _, _ = _world_cell("the box", (0.5, 0.4), (0.8, 0.1))
    assert outcome.success, outcome.message


def test_a_wrong_object_is_put_back_and_the_better_one_tried_once():
    outcome, arm, _, log = _world_cell("the box")  # retry_wrong_object is on by default
    assert outcome.success, outcome.message
    assert [a.result for a in outcome.attempts] == ["wrong_object", "success"]
    assert _put_back_index(arm.sent, outcome.attempts[0].grasp, log) > 0
    assert outcome.grasp.T_base_tcp[1, 3] == pytest.approx(-0.15, abs=0.03)  # then it held B


def test_a_wrong_object_is_put_back_in_the_place_path_too():
    # Put the box on a table spot: the check runs after the lift segment, before the transfer.
    table = PlaceTarget("surface", make_T(np.eye(3), [-0.3, 0.4, 0.0]), [0.12, 0.12])
    place = Command("put the box on the table", "place", "the box", False, "table", "the table", 1.0, 1.0)
    for retry, results in ((False, ["wrong_object"]), (True, ["wrong_object", "success"])):
        outcome, arm, _, log = _world_cell("the box", command=place, places={"table": table},
                                           retry_wrong_object=retry)  # fmt: skip
        assert [a.result for a in outcome.attempts] == results, outcome.message
        assert _put_back_index(arm.sent, outcome.attempts[0].grasp, log) > 0
    assert outcome.success and outcome.place is not None  # the retry put B on the table


def test_a_colour_the_held_object_lacks_is_a_wrong_object_without_probabilities():
    # No calibrated probabilities (NaN): the colour decides. "the blue box": A in the hand shows no blue
    # (0 % of its pixels, under 3 %), B shows it on all of them (over 25 %).
    nan = (float("nan"), float("nan"))
    outcome, arm, _, log = _world_cell("the blue box", nan, nan, retry_wrong_object=False)
    assert outcome.reason == "wrong_object", outcome.message
    assert "0 % blue pixels against 100 %" in outcome.message
    assert _put_back_index(arm.sent, outcome.attempts[0].grasp, log) > 0
    # Without a colour in the prompt nothing tells them apart: it fails closed, today's success.
    outcome, _, _, _ = _world_cell("the box", nan, nan)
    assert outcome.success and [a.result for a in outcome.attempts] == ["success"], outcome.message


def test_the_margin_is_not_judged_for_a_stack_of_like_things():
    # "top_first" takes any object that fits: a standing one scoring higher does not make the held one wrong.
    outcome, _, _, _ = _world_cell("the box", candidate_order="top_first")
    assert outcome.success and len(outcome.attempts) == 1, outcome.message


def test_wrong_object_margin_must_be_a_probability_difference():
    with pytest.raises(InvalidInputError, match="wrong_object_margin"):
        PickConfig(wrong_object_margin=1.5)


def test_a_box_hidden_behind_the_picked_object_counts_as_revealed():
    # The camera is the base frame, looking along +z. The picked object's front face stands 0.55 m away
    # (a 0.1 m cube centred 0.6 m out), the background 1.5 m: the depth image a camera would read.
    cam = CameraIntrinsics(fx=500.0, fy=500.0, cx=159.5, cy=119.5, width=320, height=240)
    u, v = np.meshgrid(np.arange(320), np.arange(240))
    x, y = (u - cam.cx) / cam.fx * 0.55, (v - cam.cy) / cam.fy * 0.55
    depth = np.where((np.abs(x) <= 0.05) & (np.abs(y) <= 0.05), 0.55, 1.5).astype(np.float32)
    frame = RGBDFrame(np.zeros((240, 320, 3), np.uint8), depth, cam, 0.0, np.eye(4))
    picked = ObjectModel("picked", Pose9D(np.eye(3), [0.0, 0.0, 0.6], [0.1, 0.1, 0.1]))
    obs = Observation(frame, None, picked, None, np.zeros((0, 3)), np.zeros(6))
    # A 5 cm can right behind it was hidden by it: every corner reads the picked object's face, nearer.
    assert revealed(Pose9D(np.eye(3), [0.0, 0.0, 0.75], [0.05, 0.05, 0.05]), obs)
    # One beside it was in plain view (the background reads farther than its corners): not revealed.
    assert not revealed(Pose9D(np.eye(3), [0.3, 0.0, 0.75], [0.05, 0.05, 0.05]), obs)
    # One in front of the picked object: nothing nearer than it there.
    assert not revealed(Pose9D(np.eye(3), [0.0, 0.0, 0.4], [0.05, 0.05, 0.05]), obs)


def test_a_candidate_seen_higher_than_before_the_pick_is_not_standing():
    rng = np.random.default_rng(0)
    box = Pose9D(np.eye(3), [0.0, 0.0, 0.04], [0.1, 0.1, 0.08])  # 8 cm tall, on the table z = 0
    # Before the pick a side camera saw it from its base up to its top; a top-down one saw only its top.
    side = np.column_stack([rng.uniform(-0.05, 0.05, 400), np.full(400, -0.05), rng.uniform(0.0, 0.08, 400)])
    top = np.column_stack([rng.uniform(-0.05, 0.05, (400, 2)), np.full(400, 0.08)])
    table = Plane.horizontal(0.0)
    for seen_before, lowest_unmoved in ((side, 0.006), (top, 0.08)):
        obs = Observation(None, None, ObjectModel("t", box), table, seen_before, np.zeros(6))
        # the same surface seen again: unmoved, standing
        assert not rose_since(box, obs, lowest_unmoved, 0.035)
        # what is seen there now starts 5 cm higher than before: a part of something in the air
        assert rose_since(box, obs, lowest_unmoved + 0.05, 0.035)
    # nothing seen there before: no evidence either way
    empty = Observation(None, None, ObjectModel("t", box), table, np.zeros((0, 3)), np.zeros(6))
    assert not rose_since(box, empty, 0.2, 0.035)
