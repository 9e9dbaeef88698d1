"""Geometry core: numpy and scipy only (an import-linter contract keeps it so).

Rigid transforms (`se3`), the 9-DoF box `Pose9D`, oriented-box IoU, camera intrinsics, point clouds
(back-projection, farthest point sampling, the paper's robust descriptor) and the Chamfer distance.
"""

from prompose_grasp.geometry.boxes import aligned_box_iou, box_corners, oriented_box_iou
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.chamfer import ChamferResult, chamfer_distance
from prompose_grasp.geometry.pointcloud import (
    RobustDescriptor,
    back_project,
    depth_to_point_map,
    farthest_point_sampling,
    robust_descriptor,
)
from prompose_grasp.geometry.pose9d import Pose9D, pose_errors

__all__ = [
    "CameraIntrinsics",
    "ChamferResult",
    "Pose9D",
    "RobustDescriptor",
    "aligned_box_iou",
    "back_project",
    "box_corners",
    "chamfer_distance",
    "depth_to_point_map",
    "farthest_point_sampling",
    "oriented_box_iou",
    "pose_errors",
    "robust_descriptor",
]
