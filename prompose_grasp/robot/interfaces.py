"""Hardware-neutral interfaces: `Arm`, `Gripper`, `RGBDCamera`, and the values they exchange.

`SimArm` (sim/), `URRtdeArm` (hardware/) and `FakeArm` (robot/fake.py) implement `Arm`; each runs every motion
command through the shared `CommandValidator` before acting and returns the command it actually sent. All
three devices are context managers: ``with arm: ...`` connects and always disconnects.

A device that fails while in use raises one of the device faults defined here, whatever its backend (the UR
adapter over RTDE, a Robotiq socket, the MuJoCo arm): `ProtectiveStopError` / `EmergencyStopError` (the
controller's safety system stopped the arm), `ConnectionLostError` (the link dropped), `MotionFailedError`
(the controller refused or did not finish a move), `GripperError` (the gripper refused or did not finish a
command). `pipeline.PickAndPlace` ends a run on any of them with a typed outcome after its stop path.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from types import TracebackType

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import DeviceFault, DeviceNotConnectedError, InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import check_depth_units
from prompose_grasp.geometry.se3 import as_transform
from prompose_grasp.robot.real_numbers import real_array


class ConnectionLostError(DeviceFault, DeviceNotConnectedError):
    """The link to a device dropped while it was in use. The adapter took its stop path (a stop command where
    the control link still answered) and marked itself disconnected; `reconnect()` or `connect()` again."""


class MotionFailedError(DeviceFault):
    """The controller refused a move, never started it, or did not finish it in time; the adapter sent a
    stop. The link is still up (check the pendant for the reason: a program running, a mode change)."""


class SafetyStopError(DeviceFault):
    """The controller stopped the arm on its own (a safety function). Nothing more is sent until it is
    cleared on the teach pendant; then call `reconnect()`."""


class ProtectiveStopError(SafetyStopError):
    """Protective stop (a collision, a force limit, a safeguard input)."""


class EmergencyStopError(SafetyStopError):
    """Emergency stop (an e-stop button or the safety system)."""


class GripperError(DeviceFault):
    """A gripper refused a command, answered something unexpected, or did not finish in time."""


@dataclass(frozen=True)
class JointTrajectory:
    """Timed joint waypoints.

    Attributes:
        t_s: (N,) float64 strictly increasing times from the start of the motion [s]; t_s[0] >= 0.
        q: (N, 6) float64 joint positions [rad].

    Both are given as numpy arrays of real floats or ints or as (nested) lists of them, and stored as
    float64 copies; bools, complex numbers and strings are refused (`robot.real_numbers`).
    """

    t_s: np.ndarray
    q: np.ndarray

    def __post_init__(self) -> None:
        t = real_array(self.t_s, "JointTrajectory.t_s [s]")
        q = real_array(self.q, "JointTrajectory.q [rad]")
        if t.ndim != 1 or q.shape != (t.shape[0], 6) or t.shape[0] < 1:
            raise InvalidInputError(
                f"JointTrajectory needs t_s (N,) and q (N, 6), N >= 1; got {t.shape}, {q.shape}"
            )
        if not np.all(np.isfinite(t)) or t[0] < 0:
            raise InvalidInputError("JointTrajectory.t_s must be finite, >= 0 and strictly increasing [s]")
        for k in np.flatnonzero(np.diff(t) <= 0)[:1]:
            jump = float(np.max(np.abs(q[k + 1] - q[k])))
            raise InvalidInputError(
                "JointTrajectory.t_s must be finite, >= 0 and strictly increasing [s]; waypoints "
                f"{k} and {k + 1} are at t = {t[k]:.6g} and {t[k + 1]:.6g} s ({jump:.6g} rad apart)"
            )
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "q", q)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])


@dataclass(frozen=True)
class JointCommand:
    """A validated joint move, as sent: target q (6,) [rad], speed [rad/s], acceleration [rad/s^2]."""

    q: np.ndarray
    speed_rad_s: float
    accel_rad_s2: float


@dataclass(frozen=True)
class LinearCommand:
    """A validated straight-line TCP move, as sent: T_base_tcp (4, 4), speed [m/s], acceleration [m/s^2]."""

    T_base_tcp: np.ndarray
    speed_m_s: float
    accel_m_s2: float


#: No pixel of a frame lies more than this far off the optical axis [deg], along u or v: pinhole (rectified)
#: RGB-D cameras see ~60-90 deg across (RealSense D435 87 x 58 deg, D405 87 x 58, Azure Kinect 90 x 59);
#: 80 deg each way (160 across) also admits any crop of such an image, whose principal point may lie outside
#: it, and refuses focal lengths or principal points that no camera has (fx = 1 px on a 640-pixel image).
_MAX_OFF_AXIS_DEG = 80.0
_MAX_OFF_AXIS_TAN = math.tan(math.radians(_MAX_OFF_AXIS_DEG))


def _timestamp(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(
            f"timestamp_s must be a finite number of seconds (int or float), got {value!r:.60}"
        )
    t = float(value)
    if not np.isfinite(t):
        raise InvalidInputError(f"timestamp_s must be a finite number of seconds, got {t}")
    return t


def _image(value: object, name: str, need: str) -> np.ndarray:
    try:
        return np.asarray(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a numpy array {need}, got {type(value).__name__}") from None


@dataclass(frozen=True)
class RGBDFrame:
    """One RGB-D capture, depth registered to the colour image.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth_m: (H, W) float32 depth along the optical axis [m]; 0, NaN, inf or a negative value where
            there is no reading. The median of the readings must lie in 5 cm - 10 m
            (`DEPTH_MEDIAN_RANGE_M`: what consumer RGB-D cameras measure): a median in the hundreds or
            thousands is refused as millimetres, a negative one as a sign mistake
            (`geometry.pointcloud.check_depth_units`).
        intrinsics: a `CameraIntrinsics` of both images (H = intrinsics.height, W = intrinsics.width) that
            puts no pixel more than 80 deg off the optical axis along u or v (a pinhole camera, or a crop of
            one). A (3, 3) matrix K is not taken as is: build the intrinsics with
            `CameraIntrinsics.from_K(K, width, height)`.
        timestamp_s: capture time [s] (device or sim clock), a finite number.
        T_base_cam: (4, 4) camera pose in the robot base frame (OpenCV camera axes) where known, else None.

    Raises:
        InvalidInputError: any of the above is not met (the message says what is accepted).
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: CameraIntrinsics
    timestamp_s: float
    T_base_cam: np.ndarray | None = None

    def __post_init__(self) -> None:
        K = self.intrinsics
        if not isinstance(K, CameraIntrinsics):
            hint = (
                "; for a (3, 3) matrix K use CameraIntrinsics.from_K(K, width, height)"
                if np.shape(K) == (3, 3)
                else ""
            )
            raise InvalidInputError(
                "intrinsics must be a prompose_grasp.geometry.CameraIntrinsics(fx, fy, cx, cy, width, "
                f"height), got {type(K).__name__}{hint}"
            )
        h, w = K.height, K.width
        # how far off the optical axis the image's edges lie, as tan(angle), along u and along v
        reach = max(max(K.cx + 0.5, w - 0.5 - K.cx) / K.fx, max(K.cy + 0.5, h - 0.5 - K.cy) / K.fy)
        if reach > _MAX_OFF_AXIS_TAN:
            raise InvalidInputError(
                f"the intrinsics (fx, fy, cx, cy) = ({K.fx:g}, {K.fy:g}, {K.cx:g}, {K.cy:g}) px put the "
                f"edge of the {w} x {h} image {math.degrees(math.atan(reach)):.1f} deg off the optical axis; "
                f"a pinhole camera (or a crop of one) sees at most {_MAX_OFF_AXIS_DEG:g} deg off it: check "
                "the focal lengths, the principal point (pixels) and the image size"
            )
        rgb = _image(self.rgb, "rgb", f"({h}, {w}, 3) uint8")
        depth = _image(self.depth_m, "depth_m", f"({h}, {w}) float32 metres")
        if rgb.shape != (h, w, 3) or rgb.dtype != np.uint8:
            raise InvalidInputError(f"rgb must be ({h}, {w}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        if depth.shape != (h, w) or depth.dtype != np.float32:
            raise InvalidInputError(
                f"depth_m must be ({h}, {w}) float32 metres, got {depth.shape} {depth.dtype}"
            )
        check_depth_units(depth, "depth_m")
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "depth_m", depth)
        object.__setattr__(self, "timestamp_s", _timestamp(self.timestamp_s))
        if self.T_base_cam is not None:
            object.__setattr__(self, "T_base_cam", as_transform(self.T_base_cam, "T_base_cam"))


class Device(abc.ABC):  # noqa: B024 - the base of the abstract Arm, Gripper and RGBDCamera
    """Something that connects: `connect()` / `disconnect()`, usable as a context manager.

    The base keeps the connected flag: devices with a real connection override `connect` / `disconnect`
    (opening sockets, stopping motion) and call `super()`; every command starts with `_require()`.
    """

    _connected: bool = False

    def connect(self) -> None:
        """Open the connection; raises a `PromposeError` subclass when the device cannot be reached."""
        self._connected = True

    def disconnect(self) -> None:
        """Close the connection; safe to call twice."""
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def _require(self) -> None:
        """Raise `DeviceNotConnectedError` unless connected (called first by every command)."""
        if not self._connected:
            raise DeviceNotConnectedError(
                f"{type(self).__name__} is not connected; call connect() or use it in a `with` block"
            )

    def __enter__(self):
        self.connect()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.disconnect()


class Arm(Device):
    """A 6-axis arm. Poses are in `base` (the controller's base frame); joints in [rad]."""

    @abc.abstractmethod
    def joint_positions(self) -> np.ndarray:
        """(6,) float64 current joint positions [rad]."""

    @abc.abstractmethod
    def tcp_pose(self) -> np.ndarray:
        """(4, 4) current T_base_tcp."""

    @abc.abstractmethod
    def move_joints(self, q: ArrayLike, speed: float, accel: float) -> JointCommand:
        """Move to joint target q (6,) [rad] at speed [rad/s] and acceleration [rad/s^2]; blocks until done.

        Returns the validated command that was sent; raises `UnsafeCommandError` (not moving) if refused."""

    @abc.abstractmethod
    def move_linear(self, T_base_tcp: ArrayLike, speed: float, accel: float) -> LinearCommand:
        """Move the TCP along a straight line to T_base_tcp (4, 4) at speed [m/s], acceleration [m/s^2]."""

    @property
    def senses_contact(self) -> bool:
        """The arm measures the external force at its tool and can stop a move at a touch
        (`move_linear_until_contact`)."""
        return False

    def move_linear_until_contact(
        self, T_base_tcp: ArrayLike, speed: float, accel: float, max_force_n: float
    ) -> bool:
        """A guarded `move_linear`: the same straight line, stopped (the arm holds where it is) as soon as the
        external force at the tool exceeds `max_force_n` [N], a touch well under the safety system's force
        limit. True when the line was completed, False when it stopped on contact. Arms that do not measure
        the force (`senses_contact` False) raise `NotImplementedError`: a caller that needs the guard must
        not get an unguarded move in its place."""
        raise NotImplementedError(f"{type(self).__name__} does not measure the force at its tool")

    @staticmethod
    def contact_force_limit(max_force_n: object) -> float:
        """`max_force_n` of a guarded move as a float [N]; `InvalidInputError` unless it is finite and > 0."""
        limit = (
            float(max_force_n)
            if isinstance(max_force_n, int | float) and not isinstance(max_force_n, bool)
            else math.nan
        )
        if not (math.isfinite(limit) and limit > 0):
            raise InvalidInputError(f"max_force_n must be finite and > 0 N, got {max_force_n!r}")
        return limit

    @abc.abstractmethod
    def follow(self, trajectory: JointTrajectory) -> JointTrajectory:
        """Stream a timed joint trajectory; returns the validated trajectory that was sent."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Decelerate to a stop now (also from another thread while a move blocks)."""


class Gripper(Device):
    """A gripper (parallel jaw, vacuum, ...); `width()` is the jaw opening [m] (0 when closed or suction)."""

    @abc.abstractmethod
    def open(self) -> None:
        """Open fully (or release the vacuum)."""

    @abc.abstractmethod
    def close(self, force: float) -> bool:
        """Close with a grip force [N] (or apply vacuum); returns `grasp_detected()` after closing."""

    @abc.abstractmethod
    def grasp_detected(self) -> bool:
        """True when an object is held (jaws stopped on an object, or vacuum established)."""

    @abc.abstractmethod
    def width(self) -> float:
        """Current opening [m]."""


class RGBDCamera(Device):
    """An RGB-D camera with depth registered to colour."""

    @abc.abstractmethod
    def capture(self) -> RGBDFrame:
        """The next frame; raises `CameraError` when none arrives."""
