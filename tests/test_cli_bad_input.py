"""`prompose-grasp` refuses bad flags before any work: exit status 2 and one line on stderr, the estimator
never loaded, no simulator started, nothing written."""

from __future__ import annotations

import pickle
import subprocess

import cv2
import numpy as np
import pytest

from prompose_grasp.cli import main
from prompose_grasp.perception import estimator as estimator_module

W, H = 64, 48
INTRINSICS = ["--intrinsics", "60", "60", "31.5", "23.5"]


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if the estimator loads or a simulator process starts."""

    def refuse(*args, **kwargs):
        raise AssertionError("work started on bad flags")

    monkeypatch.setattr(estimator_module.ProMPose, "default", classmethod(refuse))
    monkeypatch.setattr(subprocess, "call", refuse)


@pytest.fixture
def frame_files(tmp_path):
    rgb, depth = tmp_path / "000000-color.png", tmp_path / "000000-depth.png"
    cv2.imwrite(str(rgb), np.full((H, W, 3), 128, np.uint8))
    cv2.imwrite(str(depth), np.full((H, W), 800, np.uint16))  # 0.8 m in millimetres
    return rgb, depth


def _refused(argv: list[str], capsys, match: str) -> None:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"prompose-grasp {argv[0]}: error:"), err
    assert match in lines[0], err


def _estimate(frame_files, *extra: str) -> list[str]:
    rgb, depth = frame_files
    return ["estimate", "--rgb", str(rgb), "--depth", str(depth), *INTRINSICS, "--prompt", "mug", *extra]


@pytest.mark.parametrize(
    ("flags", "match"),
    [
        (["--json", "{tmp}/no/such/dir/out.json"], "does not exist"),
        (["--json", "{tmp}"], "is a folder"),
        (["--json", "{tmp}/sub/"], "is a folder"),
        (["--overlay", "{tmp}/overlay"], "unknown image extension"),
        (["--overlay", "{tmp}/overlay.txt"], "unknown image extension"),
        (["--overlay", "{tmp}"], "is a folder"),
        (["--overlay", "/no/such/dir/x.png"], "does not exist"),
        (["--max-objects", "0"], "--max-objects must be >= 1"),
        (["--max-objects", "-5"], "--max-objects must be >= 1"),
    ],
)
def test_estimate_refuses_bad_flags_before_loading(flags, match, frame_files, tmp_path, capsys, no_work):
    flags = [f.format(tmp=tmp_path) for f in flags]
    _refused(_estimate(frame_files, *flags), capsys, match)
    assert not (tmp_path / "overlay").exists() and not (tmp_path / "overlay.txt").exists()


@pytest.mark.parametrize("command", ["estimate", "track"])
def test_a_prompt_without_latin_letters_is_refused_before_loading(
    command, frame_files, tmp_path, capsys, no_work
):
    if command == "estimate":
        argv = _estimate(frame_files)
    else:
        argv = ["track", "--sequence", str(tmp_path), *INTRINSICS, "--prompt", "mug"]
    argv[argv.index("--prompt") + 1] = "赤いマグカップ"
    _refused(argv, capsys, "has no word in Latin letters")


def test_estimate_names_the_depth_scale_of_millimetres_read_as_metres(frame_files, capsys, no_work):
    _refused(_estimate(frame_files, "--depth-scale", "1"), capsys, "looks like millimetres: median 800")
    capsys.readouterr()
    main(_estimate(frame_files, "--depth-scale", "1"))
    assert "the depth scale was 1 m per unit (a millimetre PNG takes 0.001)" in capsys.readouterr().err


def test_estimate_refuses_bad_intrinsics_before_loading(frame_files, capsys, no_work):
    argv = _estimate(frame_files)
    argv[argv.index("--intrinsics") + 1] = "-60"
    _refused(argv, capsys, "fx must be finite and > 0")


def test_an_overlay_that_cannot_be_written_is_an_error_not_wrote(frame_files, tmp_path, capsys, monkeypatch):
    class NothingFound:
        def estimate_all(self, frame, prompt, max_objects=None):
            return []

    monkeypatch.setattr(estimator_module.ProMPose, "default", classmethod(lambda cls, **kw: NothingFound()))
    monkeypatch.setattr(cv2, "imwrite", lambda path, image: False)  # the disk refuses, after the checks
    overlay = tmp_path / "overlay.png"
    argv = _estimate(frame_files, "--json", str(tmp_path / "out.json"), "--overlay", str(overlay))
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "could not be written" in err and "wrote" not in err


@pytest.mark.parametrize(
    ("flags", "match"),
    [(["--json", "{tmp}/missing/out.jsonl"], "does not exist"), (["--json", "{tmp}"], "is a folder")],
)
def test_track_refuses_bad_flags_before_loading(flags, match, frame_files, tmp_path, capsys, no_work):
    flags = [f.format(tmp=tmp_path) for f in flags]
    argv = ["track", "--sequence", str(tmp_path), *INTRINSICS, "--prompt", "mug", *flags]
    _refused(argv, capsys, match)


def test_track_checks_the_first_frame_before_loading(frame_files, tmp_path, capsys, no_work):
    argv = [
        "track",
        "--sequence",
        str(tmp_path),
        "--intrinsics",
        "0.5",
        "60",
        "31.5",
        "23.5",
        "--prompt",
        "x",
    ]
    _refused(argv, capsys, "deg off the optical axis")  # fx = 0.5 px: no camera


def test_run_refuses_an_unwritable_json_before_connecting(tmp_path, capsys, no_work):
    calibration = tmp_path / "hand_eye.yaml"
    calibration.write_text("T_base_cam: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    json_out = str(tmp_path / "no" / "out.json")
    argv = ["run", "--gripper", "robotiq", "--camera", str(tmp_path), "--command", "pick up the mug",
            "--calibration", str(calibration), "--dry-run", "--json", json_out]  # fmt: skip
    _refused(argv, capsys, "does not exist")


@pytest.mark.parametrize(
    ("flags", "match"),
    [
        (["--out", "{file}"], "exists and is not a folder"),
        (["--out", "{file}/sub"], "is a file, not a folder"),
        (["--seed", "-1"], "--seed must be >= 0"),
        (["--scene", "{tmp}/missing.yaml"], "no such file"),
        (["--scene", "{bad_yaml}"], "not a readable scene file at line"),
        (["--scene", "{list_yaml}"], "holds a mapping"),
        (["--scene", "{file}"], "is .yaml, .yml or .json"),
        (["--record", "{file}"], "exists and is not a folder"),
    ],
)
def test_demo_refuses_bad_flags_before_the_episode(flags, match, tmp_path, capsys, no_work):
    paths = {"tmp": tmp_path, "file": tmp_path / "existing.txt"}
    paths["file"].write_text("not a folder")
    paths["bad_yaml"] = tmp_path / "bad.yaml"
    paths["bad_yaml"].write_text("version: 1\nobjects: [unclosed\n")
    paths["list_yaml"] = tmp_path / "list.yaml"
    paths["list_yaml"].write_text("- 1\n- 2\n")
    flags = [f.format(**paths) for f in flags]
    out = [] if "--out" in flags else ["--out", str(tmp_path / "out")]
    _refused(["demo", *out, *flags], capsys, match)


def test_eval_nocs_refuses_an_unwritable_json_and_a_crafted_pickle(tmp_path, capsys, no_work):
    _refused(["eval-nocs", str(tmp_path), "--json", str(tmp_path / "x" / "t.json")], capsys, "does not exist")
    marker = tmp_path / "payload_ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    (tmp_path / "results_0000.pkl").write_bytes(pickle.dumps({"gt_class_ids": Payload()}))
    _refused(["eval-nocs", str(tmp_path / "results_0000.pkl")], capsys, "refused to load")
    assert not marker.exists()


@pytest.mark.parametrize(
    ("flags", "match"),
    [
        (["--episodes", "0"], "--episodes must be >= 1"),
        (["--seed0", "-3"], "--seed0 must be >= 0"),
        (["--record", "{file}"], "exists and is not a folder"),
    ],
)
def test_bench_pick_refuses_bad_counts(flags, match, tmp_path, capsys, no_work):
    (tmp_path / "existing.txt").write_text("not a folder")
    flags = [f.format(file=tmp_path / "existing.txt") for f in flags]
    _refused(["bench-pick", "--scenario", "tabletop_household", *flags], capsys, match)
