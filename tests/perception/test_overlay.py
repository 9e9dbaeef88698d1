"""Overlays: labels of boxes that share a top corner (an estimate on its ground truth) are stacked, not
written over each other."""

from __future__ import annotations

import numpy as np

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.overlay import draw_poses


def test_labels_of_coincident_boxes_do_not_overlap():
    intr = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    box = Pose9D(np.eye(3), np.array([0.0, 0.05, 0.6]), np.array([0.08, 0.08, 0.08]))
    red, green = (255, 0, 0), (0, 255, 0)
    img = draw_poses(
        np.zeros((240, 320, 3), np.uint8), intr, [box, box], colors=[red, green], labels=["estimate", "truth"]
    )
    top = int(np.round(intr.project(box.corners())[:, 1].min()))
    above = img[: top - 2]  # only label text is drawn above the box's top corner
    rows_red = set(np.nonzero((above == red).all(axis=2).any(axis=1))[0])
    rows_green = set(np.nonzero((above == green).all(axis=2).any(axis=1))[0])
    assert rows_red and rows_green and not rows_red & rows_green
