"""The cell factory: a registered config builds a `Cell`, an unknown one is refused with the known names, a
cell connects its devices for a `with` block, and a loop built from a cell runs like one built from
devices."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from test_pipeline_pick_faults import PICK, ROBOT, Camera, OracleEstimator

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.grasp import get_gripper
from prompose_grasp.pipeline.cell import Cell, CellConfig, make_cell, register_cell
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig
from prompose_grasp.robot import FakeArm, FakeGripper
from prompose_grasp.robot.interfaces import RGBDCamera


class DeviceCamera(Camera, RGBDCamera):
    """The loop tests' table camera as a device (it connects)."""


@dataclass(frozen=True)
class FakeCellConfig(CellConfig):
    """A cell of fakes: the loop's own test devices."""

    object_width_m: float = 0.05


@register_cell(FakeCellConfig)
def _build_fake_cell(config: FakeCellConfig) -> Cell:
    return Cell(
        FakeArm(ROBOT),
        FakeGripper(object_width_m=config.object_width_m),
        DeviceCamera(),
        ROBOT,
        get_gripper("parallel_jaw"),
    )


class UnregisteredConfig(CellConfig):
    pass


def test_an_unregistered_config_is_refused_with_the_known_ones():
    with pytest.raises(UnknownNameError, match="FakeCellConfig"):
        make_cell(UnregisteredConfig())


def test_a_cell_refuses_a_place_target_that_is_not_one():
    with pytest.raises(InvalidInputError, match="PlaceTarget"):
        Cell(FakeArm(ROBOT), FakeGripper(), Camera(), ROBOT, get_gripper("suction"), {"bin": object()})


def test_a_cell_connects_its_devices_for_a_with_block_and_a_loop_on_it_picks():
    cell = make_cell(FakeCellConfig())
    devices = (cell.arm, cell.gripper, cell.camera)
    assert not any(d.is_connected for d in devices)
    config = PickConfig(reobserve=False, max_estimates=2, grasps_per_estimate=2)
    with cell:
        assert all(d.is_connected for d in devices)
        outcome = PickAndPlace.for_cell(cell, OracleEstimator(), config).run(PICK)
    assert not any(d.is_connected for d in devices)
    assert outcome.success, outcome.message
    # The same loop from devices, on the same scene, ends the same way.
    with FakeArm(ROBOT) as arm, FakeGripper(object_width_m=0.05) as gripper:
        again = PickAndPlace(
            arm, gripper, Camera(), OracleEstimator(), ROBOT, "parallel_jaw", config=config
        ).run(PICK)
    assert again.reason == outcome.reason and len(again.attempts) == len(outcome.attempts)
