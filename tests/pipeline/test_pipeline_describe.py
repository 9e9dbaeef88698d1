"""pipeline.describe: objects described as a person would, on hand-built estimates (known by construction)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.se3 import invert_T, make_T
from prompose_grasp.pipeline.describe import (
    colour_share,
    describe_contenders,
    object_noun,
    phrase,
    positions,
    prompt_colour,
    size_words,
)

R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
# A camera 1 m above the table (base z = 0), looking straight down: camera x = base x + 0.5 (image right).
T_BASE_CAM = make_T(np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]), [-0.5, 0.0, 1.0])


def box(t_base, size, colour: str | None = None) -> SimpleNamespace:
    """An estimate of an upright box at `t_base` (base frame) [m], its pose in the camera frame."""
    pose = Pose9D(R_UP, np.asarray(t_base, dtype=np.float64), size).transformed(invert_T(T_BASE_CAM))
    attributes = None if colour is None else SimpleNamespace(colour_name=colour)
    return SimpleNamespace(pose=pose, attributes=attributes)


def test_the_noun_and_colour_are_the_prompts_object_words():
    assert object_noun("the red box") == "box"
    assert object_noun("the small red soda can left of the bowl") == "soda can"
    assert object_noun("an apple") == "apple"  # the article, not the apple's "a"
    assert object_noun("all the cartons") == "cartons"
    assert object_noun("the red one") == "object"
    assert prompt_colour("the green bottle") == "green"
    assert prompt_colour("the gray mug") == "grey"  # the palette's spelling
    assert prompt_colour("the red and white box") is None  # two colours: none is the object's
    assert prompt_colour("the mug next to the red bowl") is None  # the colour of another thing
    assert prompt_colour("the box") is None


def test_two_boxes_side_by_side_are_left_and_right_with_their_heights():
    red = box([-0.6, 0.0, 0.085], [0.05, 0.17, 0.06], "red")  # 10 cm left of the optical axis, 17 cm tall
    blue = box([-0.4, 0.0, 0.05], [0.05, 0.10, 0.06], "blue")  # 10 cm right, 10 cm tall
    text = describe_contenders("the box", [red, blue], T_BASE_CAM)
    assert text == (
        "2 objects fit 'the box': the red box on the left, 17 cm tall; "
        "the blue box on the right, 10 cm tall. "
        'Say which one (e.g. "the red box").'
    )


def test_one_behind_the_other_is_in_front_and_behind():
    # Same image x, the second 0.3 m farther along base y (camera y), both 6 cm tall: the depth spread
    # (~4.6 cm in distance from the camera) exceeds the across-the-view one (0).
    near = box([-0.5, 0.0, 0.03], [0.05, 0.06, 0.06], "white")
    far = box([-0.5, 0.3, 0.03], [0.05, 0.06, 0.06], "white")
    assert positions(np.array([far.pose.t, near.pose.t])) == ["behind", "in front"]
    # Same colour: the example says where, not which colour.
    text = describe_contenders("the white box", [near, far], T_BASE_CAM)
    assert 'Say which one (e.g. "the white box in front")' in text
    assert "the white box behind, 6 cm tall" in text


def test_three_and_more_get_middle_and_ordinals():
    xs = np.array([[0.2, 0, 1.0], [-0.2, 0, 1.0], [0.0, 0, 1.0]])
    assert positions(xs) == ["on the right", "on the left", "in the middle"]
    four = np.array([[0.3, 0, 1.0], [-0.3, 0, 1.0], [0.1, 0, 1.0], [-0.1, 0, 1.0]])
    assert positions(four) == ["on the right", "on the left", "third from the left", "second from the left"]


def test_no_position_word_for_one_object_or_objects_on_the_same_spot():
    assert positions(np.array([[0.1, 0.0, 1.0]])) == [""]
    # 1 cm apart (under `_SAME_SPOT_M` 2 cm): estimates are ~1 cm off, so "left" would say nothing.
    assert positions(np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0]])) == ["", ""]


def test_a_flat_thing_is_described_by_its_largest_extent():
    plate = box([-0.5, 0.0, 0.01], [0.25, 0.02, 0.25], "white")  # 2 cm tall, 25 cm across
    assert size_words(plate, T_BASE_CAM) == "25 cm across"
    assert phrase(plate, "plate", "in front", T_BASE_CAM) == "the white plate in front, 25 cm across"
    assert phrase(box([-0.5, 0, 0.05], [0.05, 0.1, 0.06]), "box") == "the box"  # no colour measured


def test_more_contenders_than_estimates_are_counted():
    red = box([-0.6, 0.0, 0.05], [0.05, 0.10, 0.06], "red")
    blue = box([-0.4, 0.0, 0.05], [0.05, 0.10, 0.06], "blue")
    text = describe_contenders("the box", [red, blue], T_BASE_CAM, count=3)
    assert text.startswith("3 objects fit 'the box': ") and "; and 1 more." in text


def test_colour_share_counts_the_masked_pixels_of_that_colour():
    rgb = np.zeros((4, 4, 3), dtype=np.uint8)
    rgb[:, :2] = (200, 20, 20)  # red
    rgb[:, 2:] = (20, 20, 200)  # blue
    mask = np.zeros((4, 4), dtype=bool)
    mask[:, 1:3] = True  # 4 red and 4 blue pixels
    assert colour_share(rgb, mask, "red") == pytest.approx(0.5)
    depth = np.ones((4, 4), dtype=np.float32)
    depth[:, 2] = 0.0  # the blue half of the mask has no reading (the robot, filtered out)
    assert colour_share(rgb, mask, "red", depth) == pytest.approx(1.0)
    assert np.isnan(colour_share(rgb, None, "red"))
    assert np.isnan(colour_share(rgb, np.zeros((4, 4), dtype=bool), "red"))
    assert np.isnan(colour_share(rgb, np.ones((3, 3), dtype=bool), "red"))  # another image's mask
