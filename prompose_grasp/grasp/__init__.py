"""Grasp layer: gripper geometry, grasp synthesis, python-fcl collision scene, ranking, place planning."""

from prompose_grasp.grasp.grippers import (
    GRIPPER_KINDS,
    GRIPPER_TCP,
    GripperPart,
    ParallelJawGeometry,
    SuctionCupGeometry,
    get_gripper,
)

__all__ = [
    "GRIPPER_KINDS",
    "GRIPPER_TCP",
    "GripperPart",
    "ParallelJawGeometry",
    "SuctionCupGeometry",
    "get_gripper",
]
