"""Geometry core: numpy and scipy only (an import-linter contract keeps it so).

Rigid transforms (`se3`), the 9-DoF box `Pose9D`, oriented-box IoU, camera intrinsics, point clouds
(back-projection, farthest point sampling, the paper's robust descriptor), the Chamfer distance, and
distances and overlap tests between points, segments and oriented boxes (`distance`).
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
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

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.geometry.boxes": (
            "aligned_box_iou",
            "box_corners",
            "oriented_box_iou",
        ),
        "prompose_grasp.geometry.camera": ("CameraIntrinsics",),
        "prompose_grasp.geometry.chamfer": (
            "ChamferResult",
            "chamfer_distance",
        ),
        "prompose_grasp.geometry.pointcloud": (
            "RobustDescriptor",
            "back_project",
            "depth_to_point_map",
            "farthest_point_sampling",
            "robust_descriptor",
        ),
        "prompose_grasp.geometry.pose9d": (
            "Pose9D",
            "pose_errors",
        ),
    },
    submodules=(
        "boxes",
        "camera",
        "chamfer",
        "distance",
        "occlusion",
        "pointcloud",
        "pose9d",
        "se3",
        "tolerances",
    ),
)

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
