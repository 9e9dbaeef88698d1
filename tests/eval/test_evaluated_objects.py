"""`eval.synthetic.evaluated_objects`: a frame's ground truth under the standard CAMERA25 / REAL275 test
protocol (objects with >= 64 depth pixels in view), on a frame built by hand so every count is known."""

from __future__ import annotations

import numpy as np

from prompose_grasp.eval.synthetic import MIN_GT_DEPTH_PIXELS, evaluated_objects
from prompose_grasp.geometry import CameraIntrinsics, Pose9D
from prompose_grasp.perception.dataset import GroundTruthObject, SyntheticFrame
from prompose_grasp.robot.interfaces import RGBDFrame


def _object(instance_id: int, category: str) -> GroundTruthObject:
    pose = Pose9D(np.eye(3), [0.0, 0.0, 1.0], [0.1, 0.1, 0.1])
    return GroundTruthObject(instance_id, category, category, pose, "none", True, {})


def test_only_objects_seen_on_64_depth_pixels_are_ground_truth():
    h, w = 40, 50
    depth = np.full((h, w), 1.0, dtype=np.float32)
    mask = np.zeros((h, w), dtype=np.uint8)
    mask[0:10, 0:10] = 1  # 100 pixels, all with depth: ground truth
    mask[20:30, 0:10] = 2  # 100 pixels, 37 without a reading (0 or NaN): 63 valid, one short
    depth[20:23, 0:10] = 0.0
    depth[23, 0:7] = np.nan
    mask[20:28, 20:28] = 3  # exactly 64 pixels: ground truth (the bound is inclusive)
    mask[0:10, 30:40] = 5  # a mug seen well, but not a category asked for
    # instance 4 (hidden behind the others) has no pixel in the mask at all
    frame = RGBDFrame(
        rgb=np.zeros((h, w, 3), dtype=np.uint8),
        depth_m=depth,
        intrinsics=CameraIntrinsics(50.0, 50.0, w / 2, h / 2, w, h),
        timestamp_s=0.0,
    )
    categories = {1: "can", 2: "can", 3: "camera", 4: "can", 5: "mug"}
    objects = tuple(_object(i, c) for i, c in categories.items())
    sf = SyntheticFrame("scene", 0, frame, mask, objects)

    assert MIN_GT_DEPTH_PIXELS == 64
    assert [o.instance_id for o in evaluated_objects(sf, {"can", "camera"})] == [1, 3]
    assert [o.instance_id for o in evaluated_objects(sf, {"mug"})] == [5]
    assert evaluated_objects(sf, ()) == []
