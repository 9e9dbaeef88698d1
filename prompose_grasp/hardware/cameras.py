"""RGB-D cameras behind `RGBDCamera`: Intel RealSense, Azure Kinect, a recorded sequence, and the calibration
wrapper that stamps every frame with `T_base_cam`.

- `RealSenseCamera` (extra `realsense`, pyrealsense2): colour and depth streams, depth aligned to colour
  (`rs.align`), intrinsics of the colour stream, depth in metres through the device's depth scale.
- `AzureKinectCamera` (extra `kinect`, pyk4a): BGRA colour and the depth image transformed into the colour
  camera (`capture.transformed_depth`, millimetres), intrinsics from the colour calibration.
- `RecordedSequenceCamera`: replays a folder of `NNNNNN-color.png` / `NNNNNN-depth.png` with an
  `intrinsics.json` ({"fx", "fy", "cx", "cy", "depth_scale_m"}), for tests and offline debugging.
- `CalibratedCamera`: wraps any of them and sets `frame.T_base_cam` from a hand-eye calibration (a fixed
  camera's T_base_cam, or a wrist camera's T_flange_cam chained with the arm's current flange pose).

The SDK calls stay in `connect` / `capture`; the conversions (`frame_from_realsense`, `frame_from_kinect`,
`intrinsics_from_realsense`) take plain arrays and attribute objects, so they are tested without a device.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp._optional import require
from prompose_grasp.errors import CameraError, InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.hardware.calibration import HandEyeCalibration
from prompose_grasp.perception.frames_io import list_sequence, load_rgbd
from prompose_grasp.robot.interfaces import RGBDCamera, RGBDFrame

__all__ = [
    "AzureKinectCamera",
    "CalibratedCamera",
    "RealSenseCamera",
    "RecordedSequenceCamera",
    "frame_from_kinect",
    "frame_from_realsense",
    "intrinsics_from_realsense",
    "write_intrinsics",
]

logger = logging.getLogger(__name__)

INTRINSICS_FILE = "intrinsics.json"


# ----------------------------------------------------------------------------------------------- conversions
def intrinsics_from_realsense(intr: Any) -> CameraIntrinsics:
    """`CameraIntrinsics` of a `pyrealsense2.intrinsics` (attributes fx, fy, ppx, ppy, width, height).

    librealsense and OpenCV both put integer pixel coordinates at pixel centres, so ppx/ppy carry over.
    Distortion is ignored: the colour stream of D400 cameras is reported with (near) zero distortion.
    """
    return CameraIntrinsics(
        float(intr.fx), float(intr.fy), float(intr.ppx), float(intr.ppy), int(intr.width), int(intr.height)
    )


def frame_from_realsense(
    color_rgb: np.ndarray,
    depth_raw: np.ndarray,
    depth_scale_m: float,
    intrinsics: CameraIntrinsics,
    timestamp_ms: float,
) -> RGBDFrame:
    """An `RGBDFrame` from an aligned RealSense pair.

    Args:
        color_rgb: (H, W, 3) uint8, RGB (the stream is configured as rgb8).
        depth_raw: (H, W) uint16 depth aligned to colour, in device units (0 = no reading).
        depth_scale_m: metres per unit (`depth_sensor.get_depth_scale()`, 0.001 on most D400).
        timestamp_ms: the frame's timestamp [ms] (librealsense reports milliseconds).
    """
    if not (math.isfinite(depth_scale_m) and depth_scale_m > 0):
        raise CameraError(f"RealSense depth scale must be > 0 m per unit, got {depth_scale_m}")
    rgb = np.ascontiguousarray(np.asarray(color_rgb), dtype=np.uint8)
    raw = np.asarray(depth_raw)
    if raw.dtype != np.uint16:
        raise CameraError(f"RealSense depth must be uint16 (z16), got {raw.dtype}")
    return RGBDFrame(
        rgb=rgb,
        depth_m=raw.astype(np.float32) * np.float32(depth_scale_m),
        intrinsics=intrinsics,
        timestamp_s=float(timestamp_ms) / 1000.0,
    )


def frame_from_kinect(
    color_bgra: np.ndarray, depth_mm: np.ndarray, K: np.ndarray, timestamp_usec: float
) -> RGBDFrame:
    """An `RGBDFrame` from an Azure Kinect capture.

    Args:
        color_bgra: (H, W, 4) uint8 `capture.color` (BGRA32).
        depth_mm: (H, W) uint16 `capture.transformed_depth`, depth in the colour camera [mm] (0 = none).
        K: (3, 3) colour camera matrix (`calibration.get_camera_matrix(CalibrationType.COLOR)`).
        timestamp_usec: `capture.color_timestamp_usec` [us].
    """
    bgra = np.asarray(color_bgra)
    if bgra.ndim != 3 or bgra.shape[2] != 4 or bgra.dtype != np.uint8:
        raise CameraError(f"Kinect colour must be (H, W, 4) uint8 BGRA, got {bgra.shape} {bgra.dtype}")
    depth = np.asarray(depth_mm)
    if depth.dtype != np.uint16 or depth.shape != bgra.shape[:2]:
        raise CameraError(
            f"Kinect transformed depth must be uint16 of the colour size {bgra.shape[:2]}, got {depth.shape} "
            f"{depth.dtype}"
        )
    h, w = depth.shape
    return RGBDFrame(
        rgb=np.ascontiguousarray(bgra[..., 2::-1]),
        depth_m=depth.astype(np.float32) * np.float32(0.001),
        intrinsics=CameraIntrinsics.from_K(np.asarray(K, dtype=np.float64), width=w, height=h),
        timestamp_s=float(timestamp_usec) * 1e-6,
    )


# ----------------------------------------------------------------------------------------------- devices
class RealSenseCamera(RGBDCamera):
    """An Intel RealSense D400-series camera.

    Args:
        width, height, fps: stream format of both colour and depth (the depth is aligned to colour).
        serial: the device's serial number (None: the first one found).
        timeout_ms: longest wait for a frame pair before `CameraError`.
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        serial: str | None = None,
        timeout_ms: int = 1000,
    ):
        self.width, self.height, self.fps = int(width), int(height), int(fps)
        self.serial = serial
        self.timeout_ms = int(timeout_ms)
        self._rs: Any = None
        self._pipeline: Any = None
        self._align: Any = None
        self.depth_scale_m = float("nan")
        self.intrinsics: CameraIntrinsics | None = None

    def connect(self) -> None:
        if self._connected:
            return
        rs = require("pyrealsense2", extra="realsense")
        pipeline = rs.pipeline()
        cfg = rs.config()
        if self.serial is not None:
            cfg.enable_device(self.serial)
        cfg.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        cfg.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        try:
            profile = pipeline.start(cfg)
        except RuntimeError as exc:
            raise CameraError(
                f"could not start the RealSense camera ({self.width}x{self.height} @ {self.fps} fps"
                f"{', serial ' + self.serial if self.serial else ''}): {exc}"
            ) from exc
        self._rs, self._pipeline = rs, pipeline
        self.depth_scale_m = float(profile.get_device().first_depth_sensor().get_depth_scale())
        stream = profile.get_stream(rs.stream.color).as_video_stream_profile()
        self.intrinsics = intrinsics_from_realsense(stream.get_intrinsics())
        self._align = rs.align(rs.stream.color)
        super().connect()

    def disconnect(self) -> None:
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            except RuntimeError as exc:
                logger.warning("stopping the RealSense pipeline: %s", exc)
        self._pipeline = None
        super().disconnect()

    def capture(self) -> RGBDFrame:
        self._require()
        try:
            frames = self._pipeline.wait_for_frames(self.timeout_ms)
        except RuntimeError as exc:
            raise CameraError(f"no RealSense frame within {self.timeout_ms} ms: {exc}") from exc
        aligned = self._align.process(frames)
        color, depth = aligned.get_color_frame(), aligned.get_depth_frame()
        if not color or not depth:
            raise CameraError("the RealSense frame set lacks a colour or depth frame")
        assert self.intrinsics is not None
        return frame_from_realsense(
            np.asanyarray(color.get_data()),
            np.asanyarray(depth.get_data()),
            self.depth_scale_m,
            self.intrinsics,
            color.get_timestamp(),
        )


class AzureKinectCamera(RGBDCamera):
    """A Microsoft Azure Kinect (pyk4a).

    Args:
        color_resolution: pyk4a `ColorResolution` name ("RES_720P", "RES_1080P", ...).
        depth_mode: pyk4a `DepthMode` name ("NFOV_UNBINNED", "WFOV_2X2BINNED", ...).
        device_id: index of the device.
        timeout_ms: longest wait for a capture before `CameraError`.
    The colour camera's lens distortion is not modelled (pinhole intrinsics only).
    """

    def __init__(
        self,
        color_resolution: str = "RES_720P",
        depth_mode: str = "NFOV_UNBINNED",
        device_id: int = 0,
        timeout_ms: int = 1000,
    ):
        self.color_resolution, self.depth_mode = color_resolution, depth_mode
        self.device_id = int(device_id)
        self.timeout_ms = int(timeout_ms)
        self._k4a: Any = None
        self._K: np.ndarray | None = None

    def connect(self) -> None:
        if self._connected:
            return
        pyk4a = require("pyk4a", extra="kinect")
        try:
            resolution = getattr(pyk4a.ColorResolution, self.color_resolution)
            depth_mode = getattr(pyk4a.DepthMode, self.depth_mode)
        except AttributeError as exc:
            raise InvalidInputError(f"unknown Azure Kinect mode: {exc}") from None
        k4a = pyk4a.PyK4A(
            pyk4a.Config(
                color_resolution=resolution,
                depth_mode=depth_mode,
                color_format=pyk4a.ImageFormat.COLOR_BGRA32,
                synchronized_images_only=True,
            ),
            device_id=self.device_id,
        )
        try:
            k4a.start()
        except Exception as exc:  # pyk4a raises its own K4AException
            raise CameraError(f"could not start the Azure Kinect (device {self.device_id}): {exc}") from exc
        self._k4a = k4a
        self._K = np.asarray(k4a.calibration.get_camera_matrix(pyk4a.CalibrationType.COLOR), dtype=np.float64)
        super().connect()

    def disconnect(self) -> None:
        if self._k4a is not None:
            try:
                self._k4a.stop()
            except Exception as exc:  # K4AException
                logger.warning("stopping the Azure Kinect: %s", exc)
        self._k4a = None
        super().disconnect()

    def capture(self) -> RGBDFrame:
        self._require()
        try:
            capture = self._k4a.get_capture(timeout=self.timeout_ms)
        except Exception as exc:  # K4ATimeoutException / K4AException
            raise CameraError(f"no Azure Kinect capture within {self.timeout_ms} ms: {exc}") from exc
        if capture.color is None or capture.transformed_depth is None:
            raise CameraError("the Azure Kinect capture lacks colour or depth")
        assert self._K is not None
        return frame_from_kinect(
            capture.color, capture.transformed_depth, self._K, capture.color_timestamp_usec
        )


class RecordedSequenceCamera(RGBDCamera):
    """Replays `NNNNNN-color.png` / `NNNNNN-depth.png` frames from a folder, in order.

    Args:
        folder: the recording. Intrinsics come from `intrinsics` or the folder's `intrinsics.json`
            ({"fx", "fy", "cx", "cy", "depth_scale_m"}; depth_scale_m defaults to 0.001).
        loop: start over after the last frame (default); False raises `CameraError` at the end.
        intrinsics: (fx, fy, cx, cy) [px], overriding the file.
        depth_scale_m: metres per depth unit, overriding the file.
    Frames are stamped with their index as `timestamp_s` (plus the number of completed loops times the
    length), never with a `T_base_cam`: wrap the camera in `CalibratedCamera` for that.
    """

    def __init__(
        self,
        folder: str | Path,
        loop: bool = True,
        intrinsics: tuple[float, float, float, float] | None = None,
        depth_scale_m: float | None = None,
    ):
        self.folder = Path(folder)
        self.frames = list_sequence(self.folder)
        spec: dict[str, Any] = {}
        meta = self.folder / INTRINSICS_FILE
        if meta.is_file():
            try:
                spec = json.loads(meta.read_text())
            except json.JSONDecodeError as exc:
                raise InvalidInputError(f"{meta}: not valid JSON: {exc}") from None
        if intrinsics is None:
            missing = [k for k in ("fx", "fy", "cx", "cy") if k not in spec]
            if missing:
                raise InvalidInputError(
                    f"{self.folder}: no intrinsics: write {INTRINSICS_FILE} with fx, fy, cx, cy [px] "
                    f"(and depth_scale_m), or pass intrinsics=(fx, fy, cx, cy); missing {missing}"
                )
            intrinsics = (spec["fx"], spec["fy"], spec["cx"], spec["cy"])
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        self.fx_fy_cx_cy = (fx, fy, cx, cy)
        self.depth_scale_m = float(
            depth_scale_m if depth_scale_m is not None else spec.get("depth_scale_m", 0.001)
        )
        self.loop = bool(loop)
        self._next = 0

    def connect(self) -> None:
        super().connect()
        self._next = 0

    def capture(self) -> RGBDFrame:
        self._require()
        n = len(self.frames)
        if self._next >= n and not self.loop:
            raise CameraError(f"{self.folder}: the recording ended after {n} frame(s)")
        k = self._next
        self._next += 1
        index, rgb, depth = self.frames[k % n]
        return load_rgbd(
            rgb, depth, self.depth_scale_m, self.fx_fy_cx_cy, timestamp_s=float(index + (k // n) * n)
        )


def write_intrinsics(folder: str | Path, intrinsics: CameraIntrinsics, depth_scale_m: float = 0.001) -> Path:
    """Write `folder/intrinsics.json` for `RecordedSequenceCamera`."""
    path = Path(folder) / INTRINSICS_FILE
    path.write_text(
        json.dumps(
            {
                "fx": intrinsics.fx,
                "fy": intrinsics.fy,
                "cx": intrinsics.cx,
                "cy": intrinsics.cy,
                "width": intrinsics.width,
                "height": intrinsics.height,
                "depth_scale_m": float(depth_scale_m),
            },
            indent=2,
        )
    )
    return path


class CalibratedCamera(RGBDCamera):
    """Sets `T_base_cam` on every frame of `camera` from a hand-eye calibration.

    Args:
        camera: any `RGBDCamera`.
        calibration: `HandEyeCalibration` (fixed camera: T_base_cam; wrist camera: T_flange_cam).
        T_base_flange: for a wrist camera, returns the current (4, 4) flange pose (read right after the
            capture; hold the arm still while observing).
    """

    def __init__(
        self,
        camera: RGBDCamera,
        calibration: HandEyeCalibration,
        T_base_flange: Callable[[], np.ndarray] | None = None,
    ):
        if calibration.mount == "eye_in_hand" and T_base_flange is None:
            raise InvalidInputError("a wrist camera calibration (T_flange_cam) needs T_base_flange")
        self.camera = camera
        self.calibration = calibration
        self.T_base_flange = T_base_flange

    def connect(self) -> None:
        self.camera.connect()
        super().connect()

    def disconnect(self) -> None:
        self.camera.disconnect()
        super().disconnect()

    def capture(self) -> RGBDFrame:
        self._require()
        frame = self.camera.capture()
        return RGBDFrame(
            rgb=frame.rgb,
            depth_m=frame.depth_m,
            intrinsics=frame.intrinsics,
            timestamp_s=frame.timestamp_s,
            T_base_cam=self.calibration.T_base_cam(self.T_base_flange),
        )
