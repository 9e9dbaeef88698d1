"""The simulated cell: the scene's arm, gripper and cameras as the library's devices, built by the cell
factory (`prompose_grasp.pipeline.make_cell`) the real cell's config goes through too."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import invert_T
from prompose_grasp.grasp import PalletPattern, PlaceTarget, get_gripper
from prompose_grasp.pipeline.cell import Cell, CellConfig, register_cell
from sim.arm import SimArm
from sim.camera import SimCamera
from sim.grippers import ParallelJawGripper, SuctionGripper

__all__ = ["SIM_GRIPPERS", "SimCellConfig", "build_sim_cell", "place_targets_of"]

#: The sim's gripper device for each gripper kind of a scene.
SIM_GRIPPERS = {"parallel_jaw": ParallelJawGripper, "suction": SuctionGripper}


@dataclass(frozen=True, eq=False)
class SimCellConfig(CellConfig):
    """A cell in a built `SimWorld`.

    Attributes:
        world: the built scene (`sim.scene_file.build_scene`), with a robot and a gripper.
        camera: the fixed camera the loop observes with.
        rng: draws the cameras' sensor noise.
        wrist_camera: a camera mounted on the arm to hand to the loop too, or None.
        patterns: {place target name: PalletPattern} for the scene's pallets.
    """

    world: object
    camera: str
    rng: np.random.Generator
    wrist_camera: str | None = None
    patterns: dict[str, PalletPattern] | None = None


def place_targets_of(world, patterns: dict[str, PalletPattern] | None = None) -> dict[str, PlaceTarget]:
    """The scene's place targets as the library's `PlaceTarget`s in the arm's base frame (scene layout: what a
    user measures once when setting up a cell, not a perception result); `patterns` {place target name:
    `PalletPattern`} for pallets (the scene file's `pattern`)."""
    T_base_world = invert_T(world.T_world_base)
    kinds = {"bin": "bin", "table": "surface", "conveyor": "surface", "pallet": "pallet"}
    out: dict[str, PlaceTarget] = {}
    for support in world.place_targets.values():
        kind = kinds.get(support.kind)
        if kind is None or support.kind in out:
            continue
        name = next(n for n, s in world.place_targets.items() if s is support)
        out[support.kind] = PlaceTarget(
            kind,
            T_base_world @ support.T_world_surface,
            support.half_extents_xy_m,
            float(support.wall_height_m),
            (patterns or {}).get(name) if kind == "pallet" else None,
        )
    return out


@register_cell(SimCellConfig)
def build_sim_cell(config: SimCellConfig) -> Cell:
    """The scene's arm, gripper, cameras and place targets as a `Cell` (devices not yet connected)."""
    world: Any = config.world
    info = world.robot
    if info is None or info.gripper is None:
        raise InvalidInputError("the scene has no robot with a gripper")
    # made in this order, so that the cameras' noise streams come from `rng` as they always did
    camera = SimCamera(world, config.camera, rng=config.rng)
    wrist = SimCamera(world, config.wrist_camera, rng=config.rng) if config.wrist_camera else None
    gripper = SIM_GRIPPERS[info.gripper](world)
    return Cell(
        arm=SimArm(world),
        gripper=gripper,
        camera=camera,
        robot=info.robot,
        gripper_geometry=get_gripper(info.gripper),
        place_targets=place_targets_of(world, config.patterns),
        wrist_camera=wrist,
    )
