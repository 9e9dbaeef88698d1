"""Grounding on the tabletop scene's front camera (the pick benchmark's view, RealSense-like noise): the
cases `bench-pick` failed on because the soda can, seen through the depth noise at ~1 m, was described as
"box-shaped" (the red mug then outranked it for "soda can", and it came close to the tea box for "tea box":
seeds 25, 29, 31, 39) or the tea box as "cylindrical" (it then tied the can for "tea box": seeds 15, 136). The
ground-truth segmentation is read only to check which object the best mask covers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prompose_grasp.perception.grounding.grounder import Grounder

SCENE = Path(__file__).resolve().parents[2] / "sim" / "scenes" / "tabletop_household.yaml"


@pytest.fixture(scope="module")
def grounder():
    return Grounder()


# Seed 31: the can's box/cylinder reading sits near the threshold (ratio margin 1.10), so it scores both
# readings half (`describe.shape_families`); what sets it above the red mug whose handle is hidden is the
# soda can's size range in the object knowledge (12.2 cm tall, 6.6 cm across; the mug is 9.5 cm tall).


@pytest.mark.sim
@pytest.mark.parametrize(
    ("seed", "prompt", "name"),
    [
        (25, "soda can", "can"),
        (31, "soda can", "can"),
        (39, "soda can", "can"),
        (29, "tea box", "box"),
        (15, "tea box", "box"),
        (136, "tea box", "box"),
    ],
)
def test_the_named_object_is_the_best_candidate(grounder, seed, prompt, name):
    from sim.scene_file import build_scene, load_scene

    with build_scene(load_scene(SCENE), seed=seed) as world:
        frame = world.render("front", rng=np.random.default_rng(seed))
        oracle_ids = world.ground_truth_mask("front")  # ground truth: which object a mask covers
        ids = {o.name: o.instance_id for o in world.objects}
    result = grounder.ground(frame.rgb, frame.depth_m, frame.intrinsics, prompt)
    best = result.candidates[0]
    # Most of the best mask is the named object (the rest: edge pixels of the table behind it, ~5-10 %).
    assert np.mean(oracle_ids[best.mask] == ids[name]) > 0.8
    can = next(c for c in result.candidates if np.mean(oracle_ids[c.mask] == ids["can"]) > 0.8)
    assert can.attributes.shape_family == "cylinder"
    if name == "box":  # read "box-shaped", or near the threshold with box as the other reading
        assert "box" in (best.attributes.shape_family, best.attributes.shape_family_alternative)
