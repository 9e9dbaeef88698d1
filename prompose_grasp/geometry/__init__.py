"""Geometry core: numpy and scipy only (an import-linter contract keeps it so).

Rigid transforms (`se3`), the 9-DoF box `Pose9D`, oriented-box IoU, point clouds (back-projection, farthest
point sampling, the paper's robust descriptor) and the Chamfer distance.
"""

from prompose_grasp.geometry.pose9d import Pose9D

__all__ = ["Pose9D"]
