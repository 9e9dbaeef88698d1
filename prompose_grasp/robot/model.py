"""`RobotModel`: one UR arm with its closed-form, Pinocchio and MuJoCo kinematics, and IK; `load_robot`.

Frames: `base` is the UR controller's base frame (what ``getActualTCPPose`` is expressed in), `flange` is DH
frame 6 (ROS tool0), `tcp` is `flange` composed with the configurable offset `T_flange_tcp`. `fk(q)` follows
UR's DH convention exactly, so for a zero TCP offset it equals the controller's TCP pose.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import T_from_pose_vector, as_transform, invert_T
from prompose_grasp.robot import ik as _ik
from prompose_grasp.robot.kinematics import dh_transform, fk, fk_frames, ik_branches, nearest_in_limits
from prompose_grasp.robot.mujoco_model import ur_mjspec
from prompose_grasp.robot.ur_models import (
    DEFAULT_ROBOT,
    FLANGE_NAME,
    JOINT_NAMES,
    TCP_NAME,
    URSpec,
    get_ur_spec,
)
from prompose_grasp.robot.urdf import BASE_LINKS, describe_arm, ur_urdf

logger = logging.getLogger(__name__)

Frame = Literal["flange", "tcp"]
_FRAMES = (FLANGE_NAME, TCP_NAME)


class RobotModel:
    """A UR arm: forward kinematics three ways (closed-form DH, Pinocchio, MuJoCo), Jacobian, IK.

    Build it with `load_robot`. The Pinocchio model is built from the generated URDF text and the MuJoCo model
    from the same URDF, both created on first use.
    """

    def __init__(
        self, spec: URSpec, T_flange_tcp: ArrayLike | None = None, ik_config: _ik.IKConfig | None = None
    ):
        self.spec = spec
        self.name = spec.name
        self.T_flange_tcp = np.eye(4) if T_flange_tcp is None else as_transform(T_flange_tcp, "T_flange_tcp")
        self._T_tcp_flange = invert_T(self.T_flange_tcp)
        self.ik_config = ik_config or _ik.IKConfig()
        self.urdf: str = ur_urdf(spec)
        self.description = describe_arm(spec)
        self.joint_names: tuple[str, ...] = JOINT_NAMES
        self._lower, self._upper = spec.joint_limits
        self._solvers: dict[str, object] = {}

    def __repr__(self) -> str:
        return f"RobotModel({self.name!r}, tcp offset {self.T_flange_tcp[:3, 3].round(4).tolist()} m)"

    # ------------------------------------------------------------------ properties
    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (6,) float64 [rad]."""
        return self._lower.copy(), self._upper.copy()

    @property
    def max_joint_speed(self) -> np.ndarray:
        """(6,) float64 joint speed limits [rad/s]."""
        return np.array(self.spec.max_joint_speed_rad_s)

    @cached_property
    def pin_model(self):
        """Pinocchio model built from `self.urdf`, with an extra `tcp` operational frame."""
        import pinocchio as pin

        model = pin.buildModelFromXML(self.urdf)
        flange = model.getFrameId(FLANGE_NAME)
        frame = model.frames[flange]
        placement = frame.placement * pin.SE3(self.T_flange_tcp[:3, :3], self.T_flange_tcp[:3, 3])
        model.addFrame(pin.Frame(TCP_NAME, frame.parentJoint, flange, placement, pin.FrameType.OP_FRAME))
        return model

    @cached_property
    def _pin_data(self):
        return self.pin_model.createData()

    def mjspec(self, actuator_kp: float | None = None, support_plane_z_m: float | None = None):
        """A fresh `mujoco.MjSpec` of this arm, `flange` and `tcp` sites included (see `ur_mjspec`)."""
        return ur_mjspec(
            self.spec, self.T_flange_tcp, actuator_kp=actuator_kp, support_plane_z_m=support_plane_z_m
        )

    @cached_property
    def mj_model(self):
        """Compiled MuJoCo model of the arm alone (base at the world origin)."""
        return self.mjspec().compile()

    @cached_property
    def mj_model_with_plane(self):
        """Compiled MuJoCo model with a `support_plane` geom (moved to the configured height per solve)."""
        return self.mjspec(support_plane_z_m=0.0).compile()

    @cached_property
    def plane_checked_geoms(self) -> tuple[str, ...]:
        """Names of the capsule geoms kept off the support plane (every link but those sitting on it)."""
        return tuple(
            f"{link.name}_capsule{k}"
            for link in self.description.links
            if link.name not in BASE_LINKS
            for k in range(len(link.capsules))
        )

    # ------------------------------------------------------------------ forward kinematics
    def check_q(self, q: ArrayLike, name: str = "q") -> np.ndarray:
        """`q` as a finite (6,) float64 joint vector [rad]; `InvalidInputError` naming `name` otherwise."""
        try:
            q = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError):
            msg = f"{name} must be a finite (6,) joint vector [rad], got {q!r:.50}"
            raise InvalidInputError(msg) from None
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise InvalidInputError(
                f"{name} must be a finite (6,) joint vector [rad], got shape {q.shape}: {q}"
            )
        return q

    def fk(self, q: ArrayLike) -> np.ndarray:
        """(4, 4) T_base_flange at q (6,) [rad] (closed-form DH)."""
        return fk(self.spec, self.check_q(q))

    def fk_tcp(self, q: ArrayLike) -> np.ndarray:
        """(4, 4) T_base_tcp at q (6,) [rad]."""
        return self.fk(q) @ self.T_flange_tcp

    def fk_frame(self, q: ArrayLike, frame: Frame = "flange") -> np.ndarray:
        """(4, 4) pose of `frame` ("flange" or "tcp") in `base` at q."""
        return self.fk(q) if _check_frame(frame) == FLANGE_NAME else self.fk_tcp(q)

    def fk_pinocchio(self, q: ArrayLike, frame: Frame = "flange") -> np.ndarray:
        """(4, 4) pose of `frame` from the Pinocchio model (built from the URDF)."""
        import pinocchio as pin

        model, data = self.pin_model, self._pin_data
        fid = model.getFrameId(_check_frame(frame))
        pin.forwardKinematics(model, data, self.check_q(q))
        return pin.updateFramePlacement(model, data, fid).homogeneous.copy()

    def fk_mujoco(self, q: ArrayLike, frame: Frame = "flange") -> np.ndarray:
        """(4, 4) pose of the `frame` site from the MuJoCo model (built from the same URDF)."""
        import mujoco

        model = self.mj_model
        data = mujoco.MjData(model)
        data.qpos[:] = self.check_q(q)
        mujoco.mj_kinematics(model, data)
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, _check_frame(frame))
        T = np.eye(4)
        T[:3, :3] = data.site_xmat[sid].reshape(3, 3)
        T[:3, 3] = data.site_xpos[sid]
        return T

    def link_frames(self, q: ArrayLike) -> np.ndarray:
        """(8, 4, 4) poses in `base` of the URDF link frames base, shoulder_link .. wrist_3_link, flange."""
        q = self.check_q(q)
        dh = fk_frames(self.spec, q)
        out = np.empty((8, 4, 4))
        out[0] = dh[0]
        for i in range(6):
            # URDF link i+1 is DH frame i rotated by q_i (the joint turns before the fixed DH part).
            out[i + 1] = dh[i] @ dh_transform(q[i], 0.0, 0.0, 0.0)
        out[7] = dh[6]
        return out

    def capsules_in_base(self, q: ArrayLike) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
        """Collision capsules at q: (link name, p0 (3,) [m], p1 (3,) [m], radius [m]) in `base`."""
        frames = self.link_frames(q)
        out = []
        for i, link in enumerate(self.description.links):
            T = frames[i]
            for capsule in link.capsules:
                out.append(
                    (
                        link.name,
                        T[:3, :3] @ capsule.p0 + T[:3, 3],
                        T[:3, :3] @ capsule.p1 + T[:3, 3],
                        capsule.radius_m,
                    )
                )
        return out

    def support_clearance(self, q: ArrayLike, support_plane_z_m: float = 0.0) -> float:
        """Smallest distance [m] between the plane z = `support_plane_z_m` and the arm's capsules that must
        clear it (all links but `base` and `shoulder_link`); negative when a capsule dips below the plane."""
        return min(
            min(float(p0[2]), float(p1[2])) - r - support_plane_z_m
            for name, p0, p1, r in self.capsules_in_base(q)
            if name not in BASE_LINKS
        )

    def clears_support(self, q: np.ndarray, config: _ik.IKConfig) -> bool:
        if config.support_plane_z_m is None:
            return True
        return self.support_clearance(q, config.support_plane_z_m) >= config.support_clearance_m - 1e-9

    def jacobian(self, q: ArrayLike, frame: Frame = "flange") -> np.ndarray:
        """(6, 6) Jacobian of `frame` at q: rows (linear velocity of the frame origin [m/s], angular velocity
        [rad/s]), both in `base` coordinates, per joint velocity [rad/s] (Pinocchio LOCAL_WORLD_ALIGNED)."""
        import pinocchio as pin

        model, data = self.pin_model, self._pin_data
        fid = model.getFrameId(_check_frame(frame))
        return pin.computeFrameJacobian(model, data, self.check_q(q), fid, pin.LOCAL_WORLD_ALIGNED).copy()

    # ------------------------------------------------------------------ inverse kinematics
    def _target_flange(self, T_base_target: ArrayLike, frame: str) -> np.ndarray:
        T = as_transform(T_base_target, "T_base_target")
        return T if _check_frame(frame) == FLANGE_NAME else T @ self._T_tcp_flange

    def ik(
        self,
        T_base_target: ArrayLike,
        q_seed: ArrayLike | None = None,
        frame: Frame = "flange",
        method: _ik.IKMethod = "closed_form",
        config: _ik.IKConfig | None = None,
    ) -> _ik.IKResult:
        """Joint configuration placing `frame` at `T_base_target` (4, 4), nearest `q_seed` (6,) [rad].

        Args:
            T_base_target: (4, 4) target pose of `frame` in `base` [m].
            q_seed: (6,) configuration to stay near (the arm's current one); zeros if None.
            frame: "flange" or "tcp".
            method: "closed_form" (exact branches; default), "mink" or "pinocchio" (iterative, see `ik.py`).
            config: tolerances, seeding and support plane; the model's `ik_config` if None.

        Returns:
            `IKResult`; `success` is False (with a `message`) for unreachable, out-of-limit or colliding
            targets, never a configuration that misses the target.
        """
        t0 = time.perf_counter()
        _ik.check_method(method)
        seed = np.zeros(6) if q_seed is None else self.check_q(q_seed, "q_seed")
        solve = _ik.IKProblem(self, self._target_flange(T_base_target, frame), seed, config or self.ik_config)
        if method == "closed_form":
            result = _ik.solve_closed_form(solve)
        else:
            if method not in self._solvers:
                self._solvers[method] = _ik.MinkIK(self) if method == "mink" else _ik.PinocchioCLIK(self)
            result = self._solvers[method].solve(solve)  # type: ignore[attr-defined]
        if frame == TCP_NAME:
            # Errors were measured at the flange; the offset keeps the rotation error, not the position one.
            pos, rot = _ik.pose_errors(self.fk_tcp(result.q), as_transform(T_base_target))
            result = replace(result, position_error_m=pos, rotation_error_rad=rot)
        return replace(result, solve_time_s=time.perf_counter() - t0)

    def ik_all(
        self, T_base_target: ArrayLike, q_seed: ArrayLike | None = None, frame: Frame = "flange"
    ) -> np.ndarray:
        """(M, 6) every closed-form solution within the joint limits, nearest `q_seed` first (M = 0: none).

        Each branch appears once, as its representative nearest the seed."""
        seed = np.zeros(6) if q_seed is None else self.check_q(q_seed, "q_seed")
        T = self._target_flange(T_base_target, frame)
        branches = ik_branches(self.spec, T, q6_if_singular=float(seed[5]))
        return nearest_in_limits(branches, seed, self._lower, self._upper)

    def random_configurations(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 6) configurations drawn uniformly within the joint limits [rad]."""
        return rng.uniform(self._lower, self._upper, size=(n, 6))


def _check_frame(frame: str) -> str:
    if frame not in _FRAMES:
        raise UnknownNameError("frame", frame, _FRAMES)
    return frame


def load_robot(
    name: str = DEFAULT_ROBOT,
    tcp_offset: ArrayLike | None = None,
    ik_config: _ik.IKConfig | None = None,
) -> RobotModel:
    """Load a UR arm by name: "ur3e", "ur5e" (default), "ur10e", "ur16e" or "ur5".

    Args:
        name: registry name (case-insensitive); unknown names raise `UnknownNameError` listing the known.
        tcp_offset: the TCP in the flange frame, either (4, 4) T_flange_tcp, (3,) a translation [m], or (6,) a
            UR pose vector (x, y, z [m], rx, ry, rz [rad]) as in the controller's TCP settings.
            None: tcp = flange.
        ik_config: default `IKConfig` of the model's `ik`.
    """
    return RobotModel(get_ur_spec(name), _tcp_transform(tcp_offset), ik_config)


def _tcp_transform(tcp_offset: ArrayLike | None) -> np.ndarray:
    if tcp_offset is None:
        return np.eye(4)
    arr = np.asarray(tcp_offset, dtype=np.float64)
    if arr.shape == (4, 4):
        return as_transform(arr, "tcp_offset")
    if arr.shape == (3,):
        T = np.eye(4)
        T[:3, 3] = arr
        if not np.all(np.isfinite(arr)):
            raise InvalidInputError(f"tcp_offset must be finite, got {arr}")
        return T
    if arr.shape == (6,):
        return T_from_pose_vector(arr)
    raise InvalidInputError(
        "tcp_offset must be (4, 4) T_flange_tcp, (3,) a translation [m] or (6,) a UR pose vector; "
        f"got shape {arr.shape}"
    )
