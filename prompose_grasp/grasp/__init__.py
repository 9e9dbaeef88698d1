"""Grasp layer: gripper geometry, grasp synthesis, python-fcl collision scene, ranking, place and motion.

>>> from prompose_grasp.grasp import ObjectModel, Plane, plan_grasps  # doctest: +SKIP
>>> robot = load_robot("ur5e", tcp_offset=ParallelJawGeometry().T_flange_tcp)  # doctest: +SKIP
>>> target = ObjectModel("mug", pose_cam.transformed(T_base_cam), mesh_base, family="mug")  # doctest: +SKIP
>>> plan = plan_grasps(target, robot, "parallel_jaw", others, Plane.horizontal(0.0), pts)  # doctest: +SKIP
>>> plan.best.T_base_tcp, plan.best.q, plan.rejected  # doctest: +SKIP
"""

from prompose_grasp.grasp.batch_ik import ik_branches_batch, ik_nearest_batch
from prompose_grasp.grasp.grippers import (
    GRIPPER_KINDS,
    GRIPPER_TCP,
    GripperPart,
    ParallelJawGeometry,
    SuctionCupGeometry,
    get_gripper,
)
from prompose_grasp.grasp.motion import (
    MotionConfig,
    MotionSegment,
    PickPlaceMotion,
    check_path,
    plan_pick_place,
)
from prompose_grasp.grasp.place import (
    PalletPattern,
    PalletSlot,
    PlaceConfig,
    PlacePose,
    PlaceTarget,
    pallet_layout,
    pallet_slots,
    plan_place,
)
from prompose_grasp.grasp.planner import build_scene, generate_candidates, gripper_hulls, plan_grasps
from prompose_grasp.grasp.scene import CollisionScene, Hit, obb_overlap, voxelize_points
from prompose_grasp.grasp.synthesis import Candidates, antipodal_grasps, box_grasps, suction_grasps
from prompose_grasp.grasp.types import Grasp, GraspConfig, GraspPlan, ObjectModel, Plane

__all__ = [
    "GRIPPER_KINDS",
    "GRIPPER_TCP",
    "Candidates",
    "CollisionScene",
    "Grasp",
    "GraspConfig",
    "GraspPlan",
    "GripperPart",
    "Hit",
    "MotionConfig",
    "MotionSegment",
    "ObjectModel",
    "PalletPattern",
    "PalletSlot",
    "ParallelJawGeometry",
    "PickPlaceMotion",
    "PlaceConfig",
    "PlacePose",
    "PlaceTarget",
    "Plane",
    "SuctionCupGeometry",
    "antipodal_grasps",
    "box_grasps",
    "build_scene",
    "check_path",
    "generate_candidates",
    "get_gripper",
    "gripper_hulls",
    "ik_branches_batch",
    "ik_nearest_batch",
    "obb_overlap",
    "pallet_layout",
    "pallet_slots",
    "plan_grasps",
    "plan_pick_place",
    "plan_place",
    "suction_grasps",
    "voxelize_points",
]
