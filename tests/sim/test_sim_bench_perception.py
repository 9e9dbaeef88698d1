"""The real-mesh fit benchmark's own arithmetic: which meshes count as round about their up axis, and the
summary (a failed fit counts as IoU 0). The benchmark itself reads ../shared and is not run here."""

import numpy as np
import pytest
import trimesh

from sim.bench_fit_meshes import rotationally_symmetric, summarise


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


def test_summary_counts_a_failed_fit_as_zero_and_leaves_hidden_objects_out():
    rows = [
        {"status": "ok", "iou": 0.8, "centre_error_m": 0.01},
        {"status": "ok", "iou": 0.6, "centre_error_m": 0.02},
        {"status": "ObjectNotFoundError"},
        {"status": "hidden"},
    ]
    s = summarise(rows)
    assert s["n"] == 3 and s["hidden"] == 1
    assert s["3d50"] == pytest.approx(200 / 3)  # 0.8 and 0.6 of three
    assert s["3d75"] == pytest.approx(100 / 3)
    assert s["mean_iou"] == pytest.approx(1.4 / 3)
    assert s["median_centre_error_cm"] == pytest.approx(1.5)
