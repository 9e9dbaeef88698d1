"""Faults in real MuJoCo episodes, closed loop with the embedded estimator: each ends in a typed outcome,
never a false `success`.

The object the command names is moved, swapped with another or removed between the observation and the grasp
(a person reaching into the cell: the objects are teleported when the loop announces its first grasp, before
the arm moves; or, for the contact, under a finger as the hand comes down, which presses it into the table
until the MuJoCo arm's contact-force limit stops the arm like a UR controller's protective stop). Ground truth
is read only after the run.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

pytestmark = [pytest.mark.sim, pytest.mark.slow]

SCENE = Path(__file__).resolve().parents[2] / "sim" / "scenes" / "tabletop_household.yaml"
COMMAND = "pick up the green bottle"


@pytest.fixture(scope="module")
def estimator():
    from prompose_grasp.perception.estimator import ProMPose

    return ProMPose.default()


def _episode(estimator, before_grasp=None, camera_wrapper=None, wrist=False, **config):
    """Seed 0 of the tabletop (the bottle is picked there when nothing interferes), without the wrist camera
    (its look would re-observe the changed scene before the grasp: this is about the fixed camera's view
    going stale). `before_grasp(world)` runs once, at the first grasp's "execute" event."""
    from prompose_grasp.pipeline.pick_and_place import PickConfig
    from sim.pick import run_episode

    held = {}

    def grab(world, camera):
        held["world"] = world
        return estimator

    def on_event(event):
        if event.stage == "execute" and before_grasp is not None and not held.get("done"):
            held["done"] = True
            before_grasp(held["world"])

    base = PickConfig(candidate_max_size_ratio=1.4, candidate_order="score")  # the scene file's
    cfg = dataclasses.replace(base, **config)
    result = run_episode(
        SCENE, COMMAND, None, seed=0, estimator=estimator, config=cfg, on_event=on_event,
        estimator_wrapper=grab, camera_wrapper=camera_wrapper, wrist=wrist,
    )  # fmt: skip
    return result.outcome, result.summary, held


def _shifted(world, name, dx_m, dy_m):
    T = world.T_world_obj(name)
    T[:2, 3] += (dx_m, dy_m)
    world.set_object_pose(name, T)


def test_the_object_removed_before_the_grasp_is_not_picked(estimator):
    def remove(world):  # onto the floor, 2 m away: out of the camera's view and the arm's reach
        T = world.T_world_obj("bottle")
        T[:3, 3] = (2.0, 2.0, 0.05)
        world.set_object_pose("bottle", T)

    outcome, summary, _ = _episode(estimator, remove)
    assert not outcome.success and outcome.reason in ("slipped", "not_found"), outcome.message
    assert outcome.attempts[0].result == "slipped"  # the jaws closed on nothing where it stood
    assert summary["evaluation"]["lifted_objects"] == []


def test_the_object_moved_before_the_grasp_is_not_reported_held(estimator):
    # 15 cm along the table (away from the arm's base) after the observation: the grasp closes where it
    # stood, on nothing. One round only: the stale grasp's own outcome (a second round observes it anew).
    outcome, summary, _ = _episode(estimator, lambda w: _shifted(w, "bottle", 0.0, 0.15), max_estimates=1)
    assert outcome.reason == "slipped", outcome.message
    assert summary["evaluation"]["lifted_objects"] == []


def _swap(world):
    """The can where the bottle stood, the bottle where the can stood (each at its own height)."""
    Tb, Tc = world.T_world_obj("bottle"), world.T_world_obj("can")
    Tb2, Tc2 = Tb.copy(), Tc.copy()
    Tb2[:2, 3], Tc2[:2, 3] = Tc[:2, 3], Tb[:2, 3]
    world.set_object_pose("bottle", Tb2)
    world.set_object_pose("can", Tc2)


def test_the_object_swapped_with_another_is_put_back_as_the_wrong_object(estimator):
    # The grasp planned on the bottle closes on the can and lifts it. After the lift the re-observation sees
    # the green bottle standing elsewhere: the can is put back and, without a retry, the run ends there.
    outcome, summary, _ = _episode(estimator, _swap, retry_wrong_object=False)
    assert outcome.reason == "wrong_object", outcome.message
    assert "put it back" in outcome.message
    assert summary["evaluation"]["lifted_objects"] == []  # nothing left in the air


def test_after_a_swap_a_success_is_the_named_object(estimator):
    # With the cell's settings (the wrist camera looks first, one retry of the better candidate) the can is
    # lifted and put back, then the bottle is picked where it now stands: the success is the named object's.
    outcome, summary, _ = _episode(estimator, _swap, wrist=True)
    assert outcome.attempts[0].result == "wrong_object", outcome.message
    assert not outcome.success or summary["evaluation"]["lifted_objects"] == ["bottle"]
    assert "can" not in summary["evaluation"]["lifted_objects"]


def _bottle_under_the_finger(world) -> None:
    """As the fingers come down on the bottle's top (tcp 6 cm above it), the bottle is moved under the left
    pad: the pad lands on its top and presses it into the table."""
    m, d = world.model, world.data
    top = 2.0 * world.T_world_obj("bottle")[2, 3] - 0.75  # standing on the 0.75 m table: centre at half
    tcp, pad = m.site("tcp").id, m.geom("pad_left").id
    done = []

    def hook(w):
        above = np.linalg.norm(d.site_xpos[tcp][:2] - w.T_world_obj("bottle")[:2, 3]) < 0.05
        if not done and above and d.site_xpos[tcp][2] < top + 0.06:
            done.append(True)
            T = w.T_world_obj("bottle")
            T[:2, 3] = d.geom_xpos[pad][:2]
            w.set_object_pose("bottle", T)

    world.add_step_hook(hook)


def test_an_object_moved_under_a_finger_stops_the_guarded_approach_at_the_touch(estimator):
    # The grasp straddles the bottle's top from above; the bottle is moved under a pad on the way down. The
    # guarded approach stops at the touch (40 N), backs off to the pre-grasp and ends the attempt
    # "collision": no protective stop, and the arm never pressed anywhere near the 150 N limit.
    outcome, summary, _ = _episode(
        estimator, _bottle_under_the_finger, max_estimates=1, grasps_per_estimate=1
    )
    assert outcome.reason == "collision", outcome.message
    assert "touched something" in outcome.message and "backed off to the pre-grasp" in outcome.message
    assert [a.result for a in outcome.attempts] == ["collision"]
    assert summary["arm_max_external_force_n"] < 150.0
    assert summary["evaluation"]["lifted_objects"] == []


def test_an_object_moved_under_a_finger_of_an_unguarded_approach_is_a_protective_stop(estimator):
    # The same, with the guard switched off: the pad presses the bottle into the table until the arm's
    # contact-force limit stops it (protective stop, the UR adapter's error); the loop ends typed, sends no
    # other motion, and says the gripper is open.
    outcome, summary, _ = _episode(
        estimator, _bottle_under_the_finger, max_estimates=1, approach_contact_force_n=None
    )
    assert outcome.reason == "protective_stop", outcome.message
    assert "contact force" in outcome.message and "pad_left <- obj_bottle" in outcome.message
    assert "the gripper is open" in outcome.message
    assert [a.result for a in outcome.attempts] == ["protective_stop"]
    assert summary["arm_max_external_force_n"] > 150.0  # the UR default force limit it stopped at
    assert summary["evaluation"]["lifted_objects"] == []
