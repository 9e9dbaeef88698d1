"""Pose9D: validation, immutability and exact round trips (matrix, NOCS sRT, unit box, frame changes)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import se3
from prompose_grasp.geometry.boxes import box_corners
from prompose_grasp.geometry.pose9d import Pose9D, pose_errors

# Round trips go through a handful of float64 products and one cube root: ~1e-15 relative; 1e-12 is headroom.
ATOL = 1e-12


def random_pose(rng: np.random.Generator) -> Pose9D:
    t = rng.normal(scale=0.5, size=3) + np.array([0.0, 0.0, 1.0])
    return Pose9D(se3.random_rotation(rng), t, rng.uniform(0.02, 0.5, 3))


@pytest.fixture
def poses() -> list[Pose9D]:
    rng = np.random.default_rng(42)
    return [random_pose(rng) for _ in range(30)]


def test_fields_are_readonly_float64_copies():
    R = np.eye(3)
    t = np.array([0.0, 0.0, 1.0], dtype=np.float32)
    p = Pose9D(R, t, [1, 2, 3])
    for a in (p.R, p.t, p.size):
        assert a.dtype == np.float64 and not a.flags.writeable
    R[0, 0] = 5.0  # the caller's array is not shared
    assert p.R[0, 0] == 1.0
    with pytest.raises(ValueError):
        p.t[0] = 1.0
    with pytest.raises(AttributeError):
        p.t = np.zeros(3)  # type: ignore[misc]


def test_validation_errors():
    with pytest.raises(InvalidInputError, match="rotation"):
        Pose9D(np.diag([1.0, 1.0, -1.0]), np.zeros(3), np.ones(3))
    with pytest.raises(InvalidInputError, match=r"Pose9D\.t"):
        Pose9D(np.eye(3), [0.0, np.nan, 1.0], np.ones(3))
    with pytest.raises(InvalidInputError, match=r"Pose9D\.t"):
        Pose9D(np.eye(3), [0.0, 1.0], np.ones(3))
    with pytest.raises(InvalidInputError, match="size"):
        Pose9D(np.eye(3), np.zeros(3), [1.0, 0.0, 1.0])
    with pytest.raises(InvalidInputError, match="size"):
        Pose9D(np.eye(3), np.zeros(3), [1.0, np.inf, 1.0])
    with pytest.raises(InvalidInputError, match="det"):
        Pose9D.from_nocs_sRT(np.diag([-1.0, 1.0, 1.0, 1.0]), np.ones(3))
    with pytest.raises(InvalidInputError, match="margin_m"):
        Pose9D(np.eye(3), np.zeros(3), np.ones(3)).contains(np.zeros((1, 3)), margin_m=-0.5)
    with pytest.raises(InvalidInputError, match="keys"):
        Pose9D.from_dict({"R": np.eye(3).tolist(), "t": [0, 0, 1]})


def test_matrix_round_trip(poses):
    for p in poses:
        T = p.to_matrix()
        np.testing.assert_allclose(T[:3, :3], p.R)
        np.testing.assert_allclose(T[:3, 3], p.t)
        assert Pose9D.from_matrix(T, p.size).allclose(p, 0.0, 0.0, 0.0)


def test_nocs_sRT_round_trip_and_meaning(poses):
    for p in poses:
        sRT, scales = p.to_nocs_sRT()
        s = np.linalg.norm(p.size)
        np.testing.assert_allclose(sRT[:3, :3], s * p.R, atol=ATOL)
        assert np.linalg.norm(scales) == pytest.approx(1.0, abs=ATOL)  # NOCS: unit bounding-box diagonal
        # NOCS maps a normalised model point x to sRT x; the unit-diagonal box corners land on our corners.
        nocs_corners = box_corners(scales)
        np.testing.assert_allclose(se3.transform_points(sRT, nocs_corners), p.corners(), atol=ATOL)
        back = Pose9D.from_nocs_sRT(sRT, scales)
        assert back.allclose(p, ATOL, ATOL, ATOL)


def test_unit_box_points_round_trip(poses):
    rng = np.random.default_rng(5)
    unit = rng.uniform(-0.5, 0.5, size=(100, 3))
    for p in poses:
        cam = p.points_to_camera(unit)
        np.testing.assert_allclose(p.points_to_unit(cam), unit, atol=ATOL)
        # Independent formula: R diag(size) x + t.
        np.testing.assert_allclose(cam, (p.R @ np.diag(p.size) @ unit.T).T + p.t, atol=ATOL)
        assert p.contains(cam).all()  # unit-box samples lie inside the metric box
        # Corners of the unit box map to the box corners.
        np.testing.assert_allclose(p.points_to_camera(box_corners(np.ones(3))), p.corners(), atol=ATOL)


def test_contains_with_margin():
    p = Pose9D(se3.so3_exp([0.0, 0.0, np.pi / 2]), [0.0, 0.0, 1.0], [0.2, 0.4, 0.6])
    # Rotated 90 deg about z: the object's x (0.2 wide) lies along camera y.
    inside = p.contains(np.array([[0.19, 0.09, 1.29], [0.21, 0.0, 1.0], [0.0, 0.11, 1.0], [0.0, 0.0, 1.31]]))
    np.testing.assert_array_equal(inside, [True, False, False, False])
    np.testing.assert_array_equal(p.contains([[0.0, 0.11, 1.0]], margin_m=0.02), [True])
    np.testing.assert_array_equal(p.contains([[0.0, 0.09, 1.0]], margin_m=-0.02), [False])


def test_transformed_and_back(poses):
    rng = np.random.default_rng(9)
    for p in poses:
        T_a_cam = se3.random_transform(rng)
        q = p.transformed(T_a_cam)
        # The box as a point set moves with the frame: corners map by T_a_cam.
        np.testing.assert_allclose(q.corners(), se3.transform_points(T_a_cam, p.corners()), atol=ATOL)
        np.testing.assert_allclose(q.to_matrix(), T_a_cam @ p.to_matrix(), atol=ATOL)
        assert q.transformed(se3.invert_T(T_a_cam)).allclose(p, ATOL, ATOL, 0.0)


def test_volume_iou_and_errors(poses):
    p, q = poses[0], poses[1]
    assert p.volume == pytest.approx(float(np.prod(p.size)))
    assert p.iou(p) == pytest.approx(1.0, abs=ATOL)
    assert p.iou(q) == pytest.approx(q.iou(p), abs=ATOL)
    shifted = Pose9D(p.R, p.t + p.R[:, 0] * 0.5 * p.size[0], p.size)  # half a box along its own x
    assert p.iou(shifted) == pytest.approx(1 / 3, abs=ATOL)
    other = Pose9D(p.R @ se3.so3_exp([0.0, 0.1, 0.0]), p.t + np.array([0.03, 0.04, 0.0]), p.size)
    rot_err, trans_err = pose_errors(p, other)
    assert rot_err == pytest.approx(0.1, abs=ATOL)
    assert trans_err == pytest.approx(0.05, abs=ATOL)


def test_dict_and_pickle_round_trip(poses):
    p = poses[3]
    assert Pose9D.from_dict(p.to_dict()).allclose(p, 0.0, 0.0, 0.0)
    q = pickle.loads(pickle.dumps(p))
    assert q.allclose(p, 0.0, 0.0, 0.0)
    assert not q.R.flags.writeable  # unpickling goes through validation again
    assert "Pose9D(R=" in repr(p)
