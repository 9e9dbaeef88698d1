"""Grasp layer: gripper geometry, grasp synthesis, python-fcl collision scene, ranking, place and motion.

>>> from prompose_grasp.grasp import ObjectModel, Plane, plan_grasps  # doctest: +SKIP
>>> robot = load_robot("ur5e", tcp_offset=ParallelJawGeometry().T_flange_tcp)  # doctest: +SKIP
>>> target = ObjectModel("mug", pose_cam.transformed(T_base_cam), mesh_base, family="mug")  # doctest: +SKIP
>>> plan = plan_grasps(target, robot, "parallel_jaw", others, Plane.horizontal(0.0), pts)  # doctest: +SKIP
>>> plan.best.T_base_tcp, plan.best.q, plan.rejected  # doctest: +SKIP
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.geometry.distance import obb_overlap
    from prompose_grasp.grasp.batch_ik import ik_branches_batch, ik_nearest_batch
    from prompose_grasp.grasp.candidates import Candidates
    from prompose_grasp.grasp.grippers import (
        GRIPPER_KINDS,
        GRIPPER_TCP,
        GripperPart,
        ParallelJawGeometry,
        SuctionCupGeometry,
        as_gripper,
        get_gripper,
    )
    from prompose_grasp.grasp.motion import (
        GripperAction,
        MotionConfig,
        MotionSegment,
        PickPlaceMotion,
        check_path,
        plan_pick_place,
    )
    from prompose_grasp.grasp.parallel_jaw import antipodal_grasps, box_grasps
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
    from prompose_grasp.grasp.planner import build_scene, gripper_hulls, plan_grasps
    from prompose_grasp.grasp.scene import CollisionScene, Hit
    from prompose_grasp.grasp.suction import suction_grasps
    from prompose_grasp.grasp.synthesis import generate_candidates
    from prompose_grasp.grasp.types import Grasp, GraspConfig, GraspPlan, ObjectModel, Plane
    from prompose_grasp.grasp.voxels import voxelize_points

__getattr__, __dir__ = attach(
    __name__,
    {
        # the separating-axis test lives in the geometry layer; the grasp layer's collision checks use it
        "prompose_grasp.geometry.distance": ("obb_overlap",),
        "prompose_grasp.grasp.batch_ik": (
            "ik_branches_batch",
            "ik_nearest_batch",
        ),
        "prompose_grasp.grasp.candidates": ("Candidates",),
        "prompose_grasp.grasp.grippers": (
            "GRIPPER_KINDS",
            "GRIPPER_TCP",
            "GripperPart",
            "ParallelJawGeometry",
            "SuctionCupGeometry",
            "as_gripper",
            "get_gripper",
        ),
        "prompose_grasp.grasp.motion": (
            "GripperAction",
            "MotionConfig",
            "MotionSegment",
            "PickPlaceMotion",
            "check_path",
            "plan_pick_place",
        ),
        "prompose_grasp.grasp.place": (
            "PalletPattern",
            "PalletSlot",
            "PlaceConfig",
            "PlacePose",
            "PlaceTarget",
            "pallet_layout",
            "pallet_slots",
            "plan_place",
        ),
        "prompose_grasp.grasp.parallel_jaw": (
            "antipodal_grasps",
            "box_grasps",
        ),
        "prompose_grasp.grasp.planner": (
            "build_scene",
            "gripper_hulls",
            "plan_grasps",
        ),
        "prompose_grasp.grasp.scene": (
            "CollisionScene",
            "Hit",
        ),
        "prompose_grasp.grasp.suction": ("suction_grasps",),
        "prompose_grasp.grasp.synthesis": ("generate_candidates",),
        "prompose_grasp.grasp.voxels": ("voxelize_points",),
        "prompose_grasp.grasp.types": (
            "Grasp",
            "GraspConfig",
            "GraspPlan",
            "ObjectModel",
            "Plane",
        ),
    },
    submodules=(
        "batch_ik",
        "broadphase",
        "candidates",
        "grippers",
        "motion",
        "parallel_jaw",
        "place",
        "planner",
        "scene",
        "self_filter",
        "suction",
        "surface",
        "synthesis",
        "types",
        "voxels",
    ),
)

__all__ = [
    "GRIPPER_KINDS",
    "GRIPPER_TCP",
    "Candidates",
    "CollisionScene",
    "Grasp",
    "GraspConfig",
    "GraspPlan",
    "GripperAction",
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
    "as_gripper",
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
