"""The cell's bins as fixtures (`grasp.bins`): which readings are the bin, and its walls as fixture boxes."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp.bins import BIN_WALL_M, bin_walls, on_bin, without_bins
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.robot.interfaces import RGBDFrame

# a 40 x 30 cm tote, walls 15 cm high, its floor 2 cm above the base's z = 0, turned 90 deg about z
_T = make_T(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.5, 0.1, 0.02])
BIN = PlaceTarget("bin", _T, [0.2, 0.15], wall_height_m=0.15)


def _base(local: list[list[float]]) -> np.ndarray:
    L = np.asarray(local, dtype=np.float64)
    return L @ _T[:3, :3].T + _T[:3, 3]


def test_readings_on_the_floor_and_walls_are_the_bin_and_what_it_holds_is_not():
    m = 0.01
    local = [
        [0.0, 0.0, 0.002],  # on the floor
        [0.205, 0.0, 0.08],  # on the +x wall (1 cm thick here)
        [-0.1, -0.16, 0.149],  # on the -y wall, at its top
        [0.0, 0.0, 0.06],  # an object standing in the bin
        [0.18, 0.1, 0.05],  # an object in a corner, 2 cm from the walls
        [0.0, 0.0, 0.30],  # above the bin, higher than its walls
        [0.3, 0.0, 0.05],  # beside the bin, 8 cm past its wall
        [0.0, 0.0, -0.05],  # under it (the table 5 cm below its floor)
    ]
    expected = [True, True, True, False, False, False, False, False]
    assert on_bin(_base(local), BIN, m).tolist() == expected
    # other kinds of place target are no bin
    table = PlaceTarget("surface", _T, [0.2, 0.15])
    assert not on_bin(_base(local), table, m).any()


def test_the_walls_are_fixture_boxes_around_the_floor_up_to_the_wall_height():
    walls = bin_walls(BIN)
    assert len(walls) == 4 and all(w.kind == "fixture" for w in walls)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for w in walls:
        # each box's corners back in the bin's frame
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        corners = w.pose.t + (signs * w.pose.size / 2) @ w.pose.R.T
        local = (corners - _T[:3, 3]) @ _T[:3, :3]
        lo, hi = np.minimum(lo, local.min(axis=0)), np.maximum(hi, local.max(axis=0))
        # no wall reaches into the space the bin holds
        inner = np.all(np.abs(local[:, :2]) < [0.2 - 1e-9, 0.15 - 1e-9], axis=1)
        assert not inner.all()
    np.testing.assert_allclose(lo, [-0.2 - BIN_WALL_M, -0.15 - BIN_WALL_M, 0.0], atol=1e-12)
    np.testing.assert_allclose(hi, [0.2 + BIN_WALL_M, 0.15 + BIN_WALL_M, 0.15], atol=1e-12)
    assert bin_walls(PlaceTarget("surface", _T, [0.2, 0.15])) == []


def test_a_frame_loses_the_bin_and_keeps_what_stands_in_it():
    """A camera 1 m above the bin's floor looking straight down: the floor is at depth 1.0, an object 10 cm
    tall in the bin at 0.9, the table 2 cm under the bin's floor (past its walls) at 1.02."""
    K = CameraIntrinsics(fx=200.0, fy=200.0, cx=63.5, cy=47.5, width=128, height=96)
    T_base_cam = make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 1.02])
    target = PlaceTarget("bin", np.eye(4) @ make_T(np.eye(3), [0.0, 0.0, 0.02]), [0.2, 0.15], 0.15)
    v, u = np.mgrid[0:96, 0:128]
    x, y = (u - K.cx) / K.fx, -(v - K.cy) / K.fy  # base x, y per unit depth
    inside = (np.abs(x) < 0.2) & (np.abs(y) < 0.15)  # the floor at depth 1.0: x, y at that depth
    depth = np.where(inside, 1.0, 1.02).astype(np.float32)
    obj = (np.abs(x) < 0.05) & (np.abs(y) < 0.05)
    depth[obj] = 0.9
    depth[0, 0] = 0.0  # no reading stays none
    frame = RGBDFrame(np.zeros((96, 128, 3), np.uint8), depth, K, 0.0, T_base_cam)
    seen = without_bins(frame, [target])
    kept = seen.depth_m > 0
    assert kept[obj].all()  # the object in the bin
    assert not kept[inside & ~obj].any()  # its floor
    # the table well past the bin's outer box stays
    far = (np.abs(x) > 0.25) | (np.abs(y) > 0.2)
    assert kept[far & (depth > 0)].all()
    assert without_bins(frame, []) is frame
    assert frame.depth_m[inside].min() > 0  # the frame itself is not edited


@pytest.mark.parametrize("kind", ["surface", "pallet"])
def test_other_place_targets_leave_the_frame_alone(kind):
    K = CameraIntrinsics(fx=50.0, fy=50.0, cx=15.5, cy=11.5, width=32, height=24)
    frame = RGBDFrame(np.zeros((24, 32, 3), np.uint8), np.ones((24, 32), np.float32), K, 0.0, np.eye(4))
    assert without_bins(frame, [PlaceTarget(kind, np.eye(4), [0.2, 0.15])]) is frame
