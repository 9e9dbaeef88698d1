"""Cameras: the recorded-sequence camera end to end, the RealSense / Kinect conversions with plain arrays,
the missing-SDK errors, and the calibration wrapper."""

from __future__ import annotations

import importlib.util
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from prompose_grasp.errors import CameraError, InvalidInputError, MissingDependencyError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.se3 import make_T, so3_exp
from prompose_grasp.hardware import (
    AzureKinectCamera,
    CalibratedCamera,
    HandEyeCalibration,
    RealSenseCamera,
    RecordedSequenceCamera,
    frame_from_kinect,
    frame_from_realsense,
    intrinsics_from_realsense,
    write_intrinsics,
)
from prompose_grasp.robot import HOME_Q, load_robot

INTR = CameraIntrinsics(500.0, 510.0, 31.5, 23.5, 64, 48)


def write_sequence(folder, n: int = 3):
    rng = np.random.default_rng(0)
    frames = []
    for k in range(n):
        rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        depth_mm = rng.integers(0, 3000, (48, 64), dtype=np.uint16)
        cv2.imwrite(str(folder / f"{k:06d}-color.png"), rgb[..., ::-1])
        cv2.imwrite(str(folder / f"{k:06d}-depth.png"), depth_mm)
        frames.append((rgb, depth_mm))
    write_intrinsics(folder, INTR, depth_scale_m=0.001)
    return frames


def test_recorded_sequence_replays_frames_in_order_and_loops(tmp_path):
    frames = write_sequence(tmp_path)
    with RecordedSequenceCamera(tmp_path) as cam:
        got = [cam.capture() for _ in range(4)]
    for k in range(3):
        np.testing.assert_array_equal(got[k].rgb, frames[k][0])  # PNG is lossless
        # uint16 millimetres -> float32 metres: one float32 rounding of v * 0.001.
        np.testing.assert_allclose(got[k].depth_m, frames[k][1] * 0.001, rtol=1e-6)
        assert got[k].intrinsics == INTR and got[k].T_base_cam is None
    np.testing.assert_array_equal(got[3].rgb, frames[0][0])  # looped
    assert [f.timestamp_s for f in got] == [0.0, 1.0, 2.0, 3.0]


def test_recorded_sequence_without_loop_ends_with_a_camera_error(tmp_path):
    write_sequence(tmp_path, n=1)
    with RecordedSequenceCamera(tmp_path, loop=False) as cam:
        cam.capture()
        with pytest.raises(CameraError, match="ended"):
            cam.capture()


def test_recorded_sequence_needs_intrinsics(tmp_path):
    write_sequence(tmp_path, n=1)
    (tmp_path / "intrinsics.json").unlink()
    with pytest.raises(InvalidInputError, match=r"intrinsics\.json"):
        RecordedSequenceCamera(tmp_path)
    cam = RecordedSequenceCamera(tmp_path, intrinsics=(500.0, 510.0, 31.5, 23.5))
    with cam:
        assert cam.capture().intrinsics == INTR


def test_realsense_conversion():
    intr = intrinsics_from_realsense(
        SimpleNamespace(fx=615.2, fy=615.9, ppx=321.1, ppy=239.4, width=64, height=48)
    )
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height) == (
        615.2,
        615.9,
        321.1,
        239.4,
        64,
        48,
    )
    rgb = np.full((48, 64, 3), 7, np.uint8)
    raw = np.arange(48 * 64, dtype=np.uint16).reshape(48, 64)
    frame = frame_from_realsense(rgb, raw, 0.00025, intr, timestamp_ms=1500.0)
    # D415-style depth units of 0.25 mm; one float32 rounding.
    np.testing.assert_allclose(frame.depth_m, raw * 0.00025, rtol=1e-6)
    assert frame.depth_m[0, 0] == 0.0 and frame.timestamp_s == 1.5
    with pytest.raises(CameraError, match="uint16"):
        frame_from_realsense(rgb, raw.astype(np.float32), 0.001, intr, 0.0)
    with pytest.raises(CameraError, match="scale"):
        frame_from_realsense(rgb, raw, 0.0, intr, 0.0)


def test_kinect_conversion_swaps_bgra_and_scales_millimetres():
    bgra = np.zeros((48, 64, 4), np.uint8)
    bgra[..., 0], bgra[..., 1], bgra[..., 2], bgra[..., 3] = 10, 20, 30, 255  # B, G, R, A
    depth = np.full((48, 64), 1234, np.uint16)
    K = np.array([[600.0, 0, 32.0], [0, 601.0, 24.0], [0, 0, 1]])
    frame = frame_from_kinect(bgra, depth, K, timestamp_usec=2_000_000)
    assert frame.rgb[0, 0].tolist() == [30, 20, 10]
    assert frame.depth_m[0, 0] == pytest.approx(1.234, rel=1e-6)  # float32 rounding of 1234 * 0.001
    assert frame.intrinsics == CameraIntrinsics(600.0, 601.0, 32.0, 24.0, 64, 48) and frame.timestamp_s == 2.0
    with pytest.raises(CameraError, match="colour size"):
        frame_from_kinect(bgra, depth[:10], K, 0)


@pytest.mark.parametrize(("cls", "module", "extra"), [(RealSenseCamera, "pyrealsense2", "realsense"),
                                                      (AzureKinectCamera, "pyk4a", "kinect")])  # fmt: skip
def test_missing_sdk_names_the_extra(cls, module, extra):
    if importlib.util.find_spec(module) is not None:
        pytest.skip(f"{module} is installed here")
    with pytest.raises(MissingDependencyError, match=rf"prompose-grasp\[{extra}\]"):
        cls().connect()


def test_calibrated_camera_stamps_fixed_and_wrist_poses(tmp_path):
    write_sequence(tmp_path, n=1)
    T_base_cam = make_T(so3_exp([0.3, -0.2, 0.1]), [0.5, 0.1, 0.8])
    with CalibratedCamera(
        RecordedSequenceCamera(tmp_path), HandEyeCalibration("eye_to_hand", T_base_cam)
    ) as cam:
        np.testing.assert_allclose(cam.capture().T_base_cam, T_base_cam, atol=1e-12)  # SVD re-orthonormalised
    robot = load_robot("ur5e")
    T_flange_cam = make_T(so3_exp([0.0, 0.0, np.pi / 2]), [0.0, 0.07, 0.03])
    wrist = HandEyeCalibration("eye_in_hand", T_flange_cam)
    with CalibratedCamera(
        RecordedSequenceCamera(tmp_path), wrist, T_base_flange=lambda: robot.fk(HOME_Q)
    ) as cam:
        np.testing.assert_allclose(cam.capture().T_base_cam, robot.fk(HOME_Q) @ T_flange_cam, atol=1e-12)
    with pytest.raises(InvalidInputError, match="T_base_flange"):
        CalibratedCamera(RecordedSequenceCamera(tmp_path), wrist)
