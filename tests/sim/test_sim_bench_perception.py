"""The first-frame perception benchmark (`sim.bench_perception`): which meshes count as round about their up
axis, which object an estimate's mask lies on, the summary's accounting, and one grounded look-alike scene
end to end."""

import numpy as np
import pytest
import trimesh

from sim.bench_perception import _which_object, perceive_one, rotationally_symmetric, summarise


def _y_up(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """trimesh builds cylinders along z; the canonical frame's up is y."""
    mesh = mesh.copy()
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    return mesh


def test_a_cylinder_and_a_cone_are_round_about_their_axis_but_not_about_another():
    can = _y_up(trimesh.creation.cylinder(radius=0.033, height=0.12, sections=64))
    cone = _y_up(trimesh.creation.cone(radius=0.05, height=0.1, sections=64))
    assert rotationally_symmetric(can)
    assert rotationally_symmetric(cone)
    # lying down, the can's axis is horizontal: a turn about the up axis moves it
    lying = trimesh.creation.cylinder(radius=0.033, height=0.12, sections=64)
    assert not rotationally_symmetric(lying)


@pytest.mark.parametrize(
    "extents",
    [
        (0.10, 0.10, 0.10),  # a cube: the same after quarter turns only, and the test turns are not quarters
        (0.16, 0.12, 0.06),  # a carton
    ],
)
def test_boxes_are_not_round(extents):
    assert not rotationally_symmetric(trimesh.creation.box(extents=extents))


def test_a_mug_with_its_handle_is_not_round():
    body = _y_up(trimesh.creation.cylinder(radius=0.04, height=0.1, sections=64))
    handle = trimesh.creation.box(extents=(0.03, 0.06, 0.01))
    handle.apply_translation((0.055, 0.0, 0.0))
    assert not rotationally_symmetric(trimesh.util.concatenate([body, handle]))


def test_an_estimate_is_on_the_object_holding_most_of_its_mask_and_half_of_it_at_least():
    instances = np.zeros((4, 10), dtype=np.int32)
    instances[:, :4] = 1
    instances[:, 4:6] = 2
    names = {1: "can", 2: "box"}
    mask = np.zeros_like(instances, dtype=bool)
    mask[:, 2:6] = True  # 8 pixels on the can, 8 on the box
    mask[:, 3] = False  # now 4 on the can, 8 on the box
    assert _which_object(mask, instances, names) == "box"
    mask[:] = False
    mask[:, 5:10] = True  # 4 on the box, 16 on the background
    assert _which_object(mask, instances, names) is None


def test_summary_counts_every_outcome_and_scores_anything_but_a_right_pick_as_zero():
    rows = [
        {"status": "right", "iou": 0.8, "centre_error_m": 0.01, "lookalike_kind": "implied"},
        {"status": "right", "iou": 0.6, "centre_error_m": 0.02, "lookalike_kind": "not_implied"},
        {"status": "wrong", "lookalike_kind": "implied"},
        {"status": "ambiguous", "ambiguous": "correct", "lookalike_kind": "not_implied"},
        {"status": "ambiguous", "ambiguous": "wrong", "lookalike_kind": "implied"},
        {"status": "not_found"},
        {"status": "hidden"},
    ]
    s = summarise(rows)
    assert (s["n"], s["hidden"], s["right"], s["wrong"], s["not_found"]) == (6, 1, 2, 1, 1)
    assert (s["ambiguous_correct"], s["ambiguous_wrong"]) == (1, 1)
    assert s["3d50"] == pytest.approx(200 / 6)  # 0.8 and 0.6 of six
    assert s["3d75"] == pytest.approx(100 / 6)
    assert s["mean_iou"] == pytest.approx(1.4 / 6)
    assert s["median_centre_error_cm"] == pytest.approx(1.5)
    assert s["implied"] == {"n": 3, "right": 1, "wrong": 1}
    assert s["not_implied"] == {"n": 2, "ambiguous_correct": 1, "wrong": 0}


@pytest.mark.sim
@pytest.mark.slow
def test_a_look_alike_scene_is_judged_against_its_construction():
    """Seed 3 of the look-alikes: two copies of one product and its bare name, so the words fit both; the
    oracle mask of the first one is a right pick whose box is scored against the truth."""
    from prompose_grasp.perception.estimator import ProMPose

    row = perceive_one("lookalikes", 3, ProMPose.default(), "name", oracle_mask=True)
    assert len(row["fitting"]) == 2 and row["lookalike_kind"] == "not_implied"
    assert row["status"] == "right" and row["chosen"] == row["object"]
    # the oracle mask of a procedural bottle: the fit's own bench rows put such boxes above 0.5
    assert row["iou"] > 0.5 and row["centre_error_m"] < 0.02
