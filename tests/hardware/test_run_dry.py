"""`prompose-grasp run --dry-run`: the real pipeline on a recorded sequence, a fake arm that records the
moves, and nothing sent to hardware.

The recorded sequence is rendered here from the MuJoCo tabletop scene (tests may import `sim`; the library
may not): one frame of the fixed `front` camera with its sensor noise, written as NNNNNN-color.png /
NNNNNN-depth.png (uint16 millimetres) plus intrinsics.json, and the camera's T_base_cam as the hand-eye
calibration file. The scene's ground truth (named `oracle_*`) is used only to check where the grasp went.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from robotiq_loopback import RobotiqLoopback
from rtde_fakes import CallLog, FakeControl, FakeLinks, FakeReceive

from prompose_grasp.cli import main
from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import T_from_pose_vector, pose_vector_from_T
from prompose_grasp.grasp import get_gripper
from prompose_grasp.hardware import CellSpec, DryRunGripper, run_command, write_intrinsics
from prompose_grasp.pipeline import PickConfig
from prompose_grasp.robot import HOME_Q, load_robot

SCENE = Path(__file__).resolve().parents[2] / "sim" / "scenes" / "tabletop_household.yaml"


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from sim.scene_file import load_world

    root = tmp_path_factory.mktemp("recording")
    seq = root / "seq"
    seq.mkdir()
    with load_world(SCENE, seed=0) as world:
        frame = world.render("front", rng=np.random.default_rng(0))
        T_base_world = world.robot.T_base_world
        oracle_bottle_base = (T_base_world @ world.T_world_obj("bottle"))[:3, 3]
    cv2.imwrite(str(seq / "000000-color.png"), frame.rgb[..., ::-1])
    depth_mm = np.round(frame.depth_m * 1000.0)
    cv2.imwrite(str(seq / "000000-depth.png"), np.clip(depth_mm, 0, 65535).astype(np.uint16))
    write_intrinsics(seq, frame.intrinsics, depth_scale_m=0.001)
    calibration = root / "hand_eye.yaml"
    calibration.write_text(yaml.safe_dump({"T_base_cam": frame.T_base_cam.tolist()}))
    return seq, calibration, oracle_bottle_base


@pytest.fixture(scope="module")
def estimator():
    """One embedded estimator for both pipeline runs (loading it is most of their time)."""
    from prompose_grasp.perception.estimator import ProMPose

    return ProMPose.default()


@pytest.mark.sim
@pytest.mark.slow
def test_dry_run_completes_a_planned_pick_and_sends_nothing(
    recording, estimator, tmp_path, capsys, monkeypatch
):
    seq, calibration, oracle_bottle_base = recording
    monkeypatch.setattr("prompose_grasp.perception.estimator.ProMPose.default", lambda *a, **k: estimator)

    def no_hardware(*args, **kwargs):
        raise AssertionError("a dry run must not open a device")

    monkeypatch.setattr("prompose_grasp.hardware.run.URRtdeArm", no_hardware)
    monkeypatch.setattr("prompose_grasp.hardware.run.RobotiqGripper", no_hardware)
    monkeypatch.setattr("prompose_grasp.hardware.run._current_q", no_hardware)
    out = tmp_path / "run.json"
    argv = ["run", "--robot", "ur5e", "--gripper", "robotiq", "--camera", str(seq),
            "--command", "pick up the green bottle", "--calibration", str(calibration),
            "--dry-run", "--json", str(out)]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "dry run" in printed and "none sent" in printed
    result = json.loads(out.read_text())
    assert result["dry_run"] is True and result["outcome"]["success"] is True
    kinds = [m.split()[0] + (" " + m.split()[1] if m.startswith("gripper") else "") for m in result["moves"]]
    # The pick: open, free move to the pre-grasp, straight approach, close, straight lift.
    assert kinds == ["gripper open", "moveJ", "moveL", "gripper close,", "moveL"]
    T_grasp = np.asarray(result["grasp_T_base_tcp"])
    # The grasp centre is on the bottle: within 2 cm of its true axis (the bottle's radius is ~3 cm; a
    # grasp further off would close on its edge or miss it).
    assert np.linalg.norm(T_grasp[:2, 3] - oracle_bottle_base[:2]) < 0.02
    approach, lift = result["linear_moves_tcp_xyz_m"]
    np.testing.assert_allclose(approach, T_grasp[:3, 3], atol=1e-9)  # the grasp pose is what was sent
    # The lift raises the object by at least what the pipeline counts as picked (moved_min_m = 5 cm).
    assert lift[2] - approach[2] >= 0.05


@pytest.mark.sim
@pytest.mark.slow
def test_dry_run_with_rerun_records_the_planned_moves(recording, estimator, tmp_path, monkeypatch):
    pytest.importorskip("rerun", reason="rerun recordings need the extra viz")
    from rerun.chunk import RrdReader

    seq, calibration, _ = recording
    monkeypatch.setattr("prompose_grasp.perception.estimator.ProMPose.default", lambda *a, **k: estimator)
    rrd = tmp_path / "dry.rrd"
    argv = ["run", "--robot", "ur5e", "--gripper", "robotiq", "--camera", str(seq),
            "--command", "pick up the green bottle", "--calibration", str(calibration),
            "--dry-run", "--rerun", str(rrd)]  # fmt: skip
    assert main(argv) == 0
    rows: dict[str, int] = {}
    for chunk in RrdReader(rrd).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    # the pick's three arm moves (moveJ to the pre-grasp, moveL approach, moveL lift), each with its planned
    # TCP path; the camera frame the loop saw; the one attempt; the outcome
    assert rows["/world/arm/tcp_planned"] == 3
    assert rows["/world/cameras/fixed/image/rgb"] >= 1 and rows["/world/grasps/attempts/1"] == 1
    assert rows["/outcome"] == 1


@pytest.mark.sim
@pytest.mark.slow
def test_real_path_sends_the_validated_moves_to_the_control_link(recording, estimator):
    """Without --dry-run: the same pick through URRtdeArm (control link replaced at our boundary, see
    rtde_fakes) and RobotiqGripper (on the loopback URCap server): what goes on the wire is exactly the
    validated commands, in order, and the run ends by stopping the controller script."""
    seq, calibration, _ = recording
    log = CallLog()
    control = FakeControl(log, moving_polls=1)
    robot = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.145])
    control.receive = FakeReceive(HOME_Q, pose_vector_from_T(robot.fk_tcp(HOME_Q)))
    links = FakeLinks(control, control.receive)
    gripper_server = RobotiqLoopback(object_position=150)  # the jaws stop on something 35 mm wide
    try:
        spec = CellSpec("ur5e", "127.0.0.1", "robotiq", str(seq), calibration)
        result = run_command(
            spec,
            "pick up the green bottle",
            estimator=estimator,
            config=PickConfig(reobserve=False),  # a recording cannot show the lifted bottle
            links=links,
            robotiq_port=gripper_server.port,
        )
    finally:
        gripper_server.close()
    assert result.outcome.success and not result.dry_run
    wire = [(name, args) for name, args in log if name in ("moveJ", "moveL", "servoJ")]
    # the pre-grasp, the approach as a guarded line in two legs (URRtdeArm reads the tool force: at the
    # approach speed down to where the jaws may meet the bottle, then at the touch speed), the lift
    assert [name for name, _ in wire] == ["moveJ", "moveL", "moveL", "moveL"]
    cfg = PickConfig()
    assert [args[1] for _, args in wire[1:]] == [
        cfg.linear_speed_m_s,
        cfg.approach_touch_speed_m_s,
        cfg.linear_speed_m_s,
    ]
    sent = result.arm_commands
    assert wire[0][1][0] == sent[0].q.tolist()  # the validated joint target, unchanged
    for (_, args), command in zip(wire[1:], sent[1:]):
        # The validated TCP pose as a UR pose vector (rotation-vector round trip: float64 rounding).
        np.testing.assert_allclose(T_from_pose_vector(args[0]), command.T_base_tcp, atol=1e-12)
        assert args[1:] == (command.speed_m_s, command.accel_m_s2, True)
    assert log.names()[0] == "setTcp" and log.names()[-2:] == ["stopScript", "disconnect"]
    assert "SET POS 255" in gripper_server.log  # closed on the bottle


@pytest.fixture(scope="module")
def places_file(tmp_path_factory):
    """The tabletop scene's bin as a place-target file, as a user would measure it in the base frame."""
    from sim.pick import place_targets_of
    from sim.scene_file import load_world

    with load_world(SCENE, seed=0) as world:
        b = place_targets_of(world)["bin"]
    path = tmp_path_factory.mktemp("cell") / "places.yaml"
    entry = {"kind": "bin", "T_base_surface": b.T_base_surface.tolist(),
             "half_extents_m": b.half_extents_xy_m.tolist(), "wall_height_m": b.wall_height_m}  # fmt: skip
    path.write_text(yaml.safe_dump({"place_targets": {"bin": entry}}))
    return path, b


@pytest.mark.sim
@pytest.mark.slow
def test_dry_run_puts_the_bottle_into_the_bin_of_the_places_file(recording, estimator, places_file):
    seq, calibration, _ = recording
    path, oracle_bin = places_file
    spec = CellSpec("ur5e", None, "robotiq", str(seq), calibration, dry_run=True, places=path)
    result = run_command(spec, "put the green bottle in the bin", estimator=estimator)
    assert result.outcome.success, result.outcome.message
    assert [m for m in result.moves if m.startswith("gripper")][-2:] == [
        "gripper close, force 60.0 N -> holding",
        "gripper open",
    ]
    # The release: the arm's last command before the jaws open again ends over the bin's floor, i.e. the
    # TCP lies inside the floor's footprint (half extents; the planner keeps the whole object inside it) and
    # between the floor and a hand's height above the walls (the object is let go just above the floor).
    n_before_release = sum(
        1 for m in result.moves[: result.moves.index("gripper open", 1)] if not m.startswith("gripper")
    )
    q_release = result.arm_commands[n_before_release - 1].q[-1]
    robot = load_robot("ur5e", tcp_offset=get_gripper("parallel_jaw").T_flange_tcp)
    tcp_in_bin = np.linalg.inv(oracle_bin.T_base_surface) @ robot.fk_tcp(q_release)[:, 3]
    assert np.all(np.abs(tcp_in_bin[:2]) <= oracle_bin.half_extents_xy_m)
    assert 0.0 < tcp_in_bin[2] < oracle_bin.wall_height_m + 0.25


def test_cli_run_refuses_a_bad_places_file_with_exit_2(tmp_path, capsys):
    (tmp_path / "000000-color.png").write_bytes(b"")
    (tmp_path / "000000-depth.png").write_bytes(b"")
    cal = tmp_path / "cal.yaml"
    cal.write_text(yaml.safe_dump({"T_base_cam": np.eye(4).tolist()}))
    places = tmp_path / "places.yaml"
    places.write_text(yaml.safe_dump({"place_targets": {"shelf": {"kind": "surface"}}}))
    argv = ["run", "--gripper", "robotiq", "--camera", str(tmp_path), "--command", "put the mug in the bin",
            "--calibration", str(cal), "--places", str(places), "--dry-run"]  # fmt: skip
    assert main(argv) == 2
    assert "'shelf' is not a fixture a command can name" in capsys.readouterr().err


def test_cell_spec_checks_its_choices(tmp_path):
    with pytest.raises(UnknownNameError, match="robotiq, suction"):
        CellSpec("ur5e", "10.0.0.2", "magnet", "realsense", "cal.yaml")
    with pytest.raises(InvalidInputError, match="--host"):
        CellSpec("ur5e", None, "robotiq", "realsense", "cal.yaml")
    with pytest.raises(UnknownNameError, match="realsense, kinect"):
        CellSpec("ur5e", "10.0.0.2", "robotiq", str(tmp_path / "missing"), "cal.yaml")


def test_cli_run_refuses_a_bad_calibration_with_exit_2(tmp_path, capsys):
    (tmp_path / "000000-color.png").write_bytes(b"")
    (tmp_path / "000000-depth.png").write_bytes(b"")
    bad = tmp_path / "cal.yaml"
    bad.write_text(yaml.safe_dump({"T_base_cam": np.diag([1.0, 2.0, 1.0, 1.0]).tolist()}))
    argv = ["run", "--gripper", "robotiq", "--camera", str(tmp_path), "--command", "pick up the mug",
            "--calibration", str(bad), "--dry-run"]  # fmt: skip
    assert main(argv) == 2
    assert "not a rotation" in capsys.readouterr().err


def test_dry_run_gripper_reports_its_geometry_s_widths():
    """The dry-run gripper's widths follow from the gripper geometry's type: the jaws' stroke while open and
    half of it once closed on something; a suction cup has no jaws and reports 0 m throughout."""
    jaws = DryRunGripper(get_gripper("parallel_jaw"))
    with jaws:
        assert jaws.width() == get_gripper("parallel_jaw").stroke_m
        assert jaws.close(50.0) and jaws.grasp_detected()
        assert jaws.width() == 0.5 * get_gripper("parallel_jaw").stroke_m
    cup = DryRunGripper(get_gripper("suction"))
    with cup:
        assert cup.width() == 0.0
        assert cup.close(50.0)
        assert cup.width() == 0.0
    with pytest.raises(InvalidInputError, match="ParallelJawGeometry or SuctionCupGeometry"):
        DryRunGripper("suction")
