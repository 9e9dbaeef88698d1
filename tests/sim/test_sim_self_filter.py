"""Robot self-filtering on a rendered MuJoCo scene: with the UR5e parked in the front camera's view, the
arm's pixels are dropped and no object pixel is (`grasp.self_filter.robot_pixel_mask`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prompose_grasp.grasp import get_gripper
from prompose_grasp.grasp.self_filter import robot_pixel_mask, robot_self_capsules

SCENE = Path(__file__).resolve().parents[2] / "sim" / "scenes" / "tabletop_household.yaml"


@pytest.mark.sim
def test_the_parked_arm_is_filtered_and_no_object_pixel_is():
    from sim.arm import SimArm
    from sim.scene_file import build_scene, load_scene

    with build_scene(load_scene(SCENE), seed=29) as world:
        frame = world.render("front", rng=np.random.default_rng(29))
        objects = world.ground_truth_mask("front") > 0  # ground truth: test only
        with SimArm(world) as arm:
            q = arm.joint_positions()
        robot = world.robot.robot
    capsules = robot_self_capsules(robot, get_gripper("parallel_jaw"), q)
    mask = robot_pixel_mask(frame.depth_m, frame.intrinsics, frame.T_base_cam, capsules, 0.03)
    # The front camera sees the parked UR5e (about 11k pixels of 640 x 480 on this seed).
    assert mask.sum() > 5000
    # Not one pixel of the six objects on the table is taken for the robot.
    assert not (mask & objects).any()
