"""Recording a simulated episode at a fixed control rate, and replaying its actions.

`EpisodeRecorder` is a step hook of the `SimWorld` (`SimWorld.add_step_hook`): every physics step runs it, and
every `1 / fps` seconds of sim time it samples

- the observation: the arm's measured joint positions [rad], the TCP pose in the arm's base frame (position
  [m] and quaternion wxyz), the gripper's opening [m] and whether it holds something; and one colour image
  from each recorded camera (the scene's fixed camera the loop observes with, "front", and the first camera
  mounted on the arm, "wrist");
- the action: what the arm and gripper are commanded at that tick: the arm's joint set-point [rad] (before the
  velocity feed-forward, `SimArm.commanded_joint_positions`) and the gripper's command and force limit
  (`command()` of the sim grippers).

Sampling never changes the physics: the images and the TCP pose come from a scratch `MjData` holding a copy of
the positions (rendering on the world's own data would recompute its body poses mid-step, which the suction
cup's load check reads), so an episode is the same with recording on or off. The defaults keep
recording cheap on CPUs: 20 Hz (a usual control rate of lerobot's arm datasets; the 500 Hz physics rate is a
whole multiple of it), 160 x 120 images without shadows (a few ms per image with software OpenGL,
`RecordConfig.shadows`): a tabletop place episode (~13.6 s of sim time, 270 frames) took ~4 s more wall
time with recording (~14 ms a frame: two renders, state, encoding); all settable.

`replay_episode` drives a freshly built copy of the scene with the recorded actions through `SimArm.servo`
and the gripper's `apply_command`, interpolating the set-points between ticks (monotone cubic, as
`SimArm.follow`), and returns the joint trajectory it produced at the same ticks.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.robot.interfaces import ProtectiveStopError

__all__ = [
    "ACTION_NAMES",
    "JOINT_NAMES",
    "STATE_NAMES",
    "EpisodeRecorder",
    "RecordConfig",
    "RecordedEpisode",
    "recorded_cameras",
    "replay_episode",
    "replay_in_scene",
]

log = logging.getLogger(__name__)

#: The UR arm's joints, base to wrist.
JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
#: observation.state: joints [rad], TCP position in the arm's base [m] and orientation (unit quaternion wxyz),
#: gripper opening [m] (0 for a suction cup), holding (1.0 when the gripper holds an object, else 0.0).
STATE_NAMES = (
    *JOINT_NAMES,
    *("tcp_x", "tcp_y", "tcp_z", "tcp_qw", "tcp_qx", "tcp_qy", "tcp_qz"),
    "gripper_width",
    "gripper_holding",
)
#: action: joint set-points [rad]; gripper command (parallel jaw: target opening [m], below 0 while squeezing;
#: suction: vacuum 1.0 on / 0.0 off); gripper force limit [N].
ACTION_NAMES = (*JOINT_NAMES, "gripper_command", "gripper_force")


@dataclass(frozen=True)
class RecordConfig:
    """What an episode recording samples.

    Attributes:
        fps: control rate [Hz]; the physics rate (500 Hz at the 2 ms step) must be a whole multiple of it.
        width, height: recorded image size [px] (every camera rendered at this size, its own field of view).
        shadows: render shadows and reflections. Off by default: their cost does not shrink with the image
            (a 1024 x 1024 shadow map per light and image); with software OpenGL a 160 x 120 frame of the
            tabletop took 44 ms with them and 3-7 ms without.
    """

    fps: int = 20
    width: int = 160
    height: int = 120
    shadows: bool = False

    def __post_init__(self) -> None:
        for name in ("fps", "width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise InvalidInputError(f"RecordConfig.{name} must be a positive integer, got {v!r}")
        if self.width % 2 or self.height % 2:  # yuv420p video halves the chroma planes
            raise InvalidInputError(f"image size must be even, got {self.width} x {self.height}")


@dataclass(frozen=True, eq=False)
class RecordedEpisode:
    """One recorded episode, n frames at `fps`.

    Attributes:
        fps: frames per second. t0_sim_s: sim time of frame 0 [s].
        state: (n, len(STATE_NAMES)) float32. action: (n, len(ACTION_NAMES)) float32.
        images: {camera key ("front", "wrist"): (n, H, W, 3) uint8 RGB}.
        cameras: {camera key: the scene camera's name}.
        gripper: the gripper kind ("parallel_jaw" | "suction"). robot: the arm's model ("ur5e").
    """

    fps: int
    t0_sim_s: float
    state: np.ndarray
    action: np.ndarray
    images: dict[str, np.ndarray]
    cameras: dict[str, str]
    gripper: str
    robot: str = ""

    @property
    def num_frames(self) -> int:
        return len(self.state)

    def lerobot_frames(self) -> dict[str, np.ndarray]:
        """The episode as the frames of `lerobot_features()`."""
        out = {"observation.state": self.state, "action": self.action}
        out.update({f"observation.images.{k}": v for k, v in self.images.items()})
        return out

    def lerobot_features(self) -> dict[str, dict]:
        """The LeRobot dataset features of this recording (`sim.lerobot_dataset.LeRobotDatasetWriter`)."""
        features = {
            key: {"dtype": "float32", "shape": [len(names)], "names": list(names)}
            for key, names in (("observation.state", STATE_NAMES), ("action", ACTION_NAMES))
        }
        for key, images in self.images.items():
            features[f"observation.images.{key}"] = {
                "dtype": "video",
                "shape": list(images.shape[1:]),
                "names": ["height", "width", "channels"],
            }
        return features


def recorded_cameras(world, fixed_camera: str) -> dict[str, str]:
    """{"front": the fixed camera, "wrist": the first camera mounted on the arm (when the scene has one)}."""
    cameras = {"front": fixed_camera}
    mounted = [n for n, spec in world.cameras.items() if spec.parent_body is not None]
    if mounted:
        cameras["wrist"] = mounted[0]
    return cameras


class EpisodeRecorder:
    """Samples a running episode every `1 / config.fps` s of sim time (a step hook; module docstring).

    Args:
        world: the `SimWorld`. arm: its `SimArm`. gripper: its sim gripper (connected while recording).
        cameras: {key: scene camera name}, e.g. `recorded_cameras(world, "front")`.
        config: rate and image size.

    `start()` samples frame 0 and hooks into the world; `stop()` unhooks and returns the `RecordedEpisode`
    (the frames up to the last full control period).
    """

    def __init__(self, world, arm, gripper, cameras: dict[str, str], config: RecordConfig | None = None):
        self.config = config or RecordConfig()
        dt = float(world.model.opt.timestep)
        every = round(1.0 / (self.config.fps * dt))
        if every < 1 or abs(every * dt * self.config.fps - 1.0) > 1e-9:
            rate = 1.0 / dt
            fits = [str(f) for f in (10, 20, 25, 50) if abs(rate / f - round(rate / f)) < 1e-9]
            raise InvalidInputError(
                f"fps {self.config.fps} does not divide the physics rate {rate:g} Hz; use one that does, "
                f"e.g. {', '.join(fits)}"
            )
        unknown = [c for c in cameras.values() if c not in world.cameras]
        if unknown:
            raise InvalidInputError(f"cameras {unknown} are not in the scene; known: {sorted(world.cameras)}")
        m = world.model
        if self.config.width > m.vis.global_.offwidth or self.config.height > m.vis.global_.offheight:
            raise InvalidInputError(
                f"image size {self.config.width} x {self.config.height} exceeds the scene's offscreen "
                f"buffer {m.vis.global_.offwidth} x {m.vis.global_.offheight}"
            )
        self.world, self.arm, self.gripper = world, arm, gripper
        self.cameras = dict(cameras)
        self.every = every
        self._scratch = mujoco.MjData(m)
        self._renderer: mujoco.Renderer | None = None
        self._n = 0
        self._t0 = 0.0
        self._state: list[np.ndarray] = []
        self._action: list[np.ndarray] = []
        self._images: dict[str, list[np.ndarray]] = {k: [] for k in cameras}
        self._running = False

    def start(self) -> None:
        if self._running:
            raise InvalidInputError("the recorder is already running")
        self._renderer = mujoco.Renderer(self.world.model, height=self.config.height, width=self.config.width)
        self._running = True
        self._n = 0
        self._t0 = float(self.world.data.time)
        self._sample()
        self.world.add_step_hook(self)

    def __call__(self, world) -> None:
        self._n += 1
        if self._n % self.every == 0:
            self._sample()

    def _sample(self) -> None:
        m, d, s = self.world.model, self.world.data, self._scratch
        info = self.world.robot
        s.qpos[:] = d.qpos
        s.mocap_pos[:] = d.mocap_pos
        s.mocap_quat[:] = d.mocap_quat
        s.time = d.time
        mujoco.mj_kinematics(m, s)
        mujoco.mj_camlight(m, s)
        b = info.flange_body
        T_world_flange = make_T(s.xmat[b].reshape(3, 3), s.xpos[b])
        T_base_tcp = info.T_base_world @ T_world_flange @ self.arm.robot.T_flange_tcp
        x, y, z, w = Rotation.from_matrix(T_base_tcp[:3, :3]).as_quat()
        quat = np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)  # one sign of q == -q: w >= 0
        state = np.concatenate(
            [
                d.qpos[info.qpos_adr],
                T_base_tcp[:3, 3],
                quat,
                [self.gripper.width(), 1.0 if self.gripper.grasp_detected() else 0.0],
            ]
        )
        command, force = self.gripper.command()
        action = np.concatenate([self.arm.commanded_joint_positions(), [command, force]])
        self._state.append(state.astype(np.float32))
        self._action.append(action.astype(np.float32))
        r = self._renderer
        for key, cam in self.cameras.items():
            r.update_scene(s, camera=cam)
            if not self.config.shadows:
                r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
                r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
            self._images[key].append(r.render().copy())

    def stop(self) -> RecordedEpisode:
        if not self._running:
            raise InvalidInputError("the recorder is not running")
        self.world.remove_step_hook(self)
        self._running = False
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        return RecordedEpisode(
            fps=self.config.fps,
            t0_sim_s=self._t0,
            state=np.stack(self._state),
            action=np.stack(self._action),
            images={k: np.stack(v) for k, v in self._images.items()},
            cameras=dict(self.cameras),
            gripper=str(self.world.robot.gripper),
            robot=str(self.world.robot.name),
        )


def replay_episode(world, arm, gripper, action: np.ndarray, fps: int) -> np.ndarray:
    """Drive the scene with recorded actions and return the joint positions it reaches at the ticks.

    Args:
        world: the scene, rebuilt as it was when the recording started (same file and seed).
        arm, gripper: its connected `SimArm` and sim gripper.
        action: (n, len(ACTION_NAMES)) the recorded actions, one per tick of `1 / fps` s.

    Returns:
        (n, 6) float64 measured joint positions [rad] at the ticks (row 0: before any step).

    Between ticks the arm's set-point follows a monotone cubic (PCHIP) through the recorded set-points, with
    its speed and acceleration as feed-forward (`SimArm.servo`); a parallel jaw's target opening moves
    linearly between ticks; force limits and a suction cup's vacuum switch at the start of the period in which
    the recording saw them change (the recording only knows the period, not the step).
    """
    action = np.asarray(action, dtype=np.float64)
    if action.ndim != 2 or action.shape[1] != len(ACTION_NAMES) or len(action) < 1:
        raise InvalidInputError(f"action must be (n >= 1, {len(ACTION_NAMES)}), got {action.shape}")
    dt = float(world.model.opt.timestep)
    every = round(1.0 / (fps * dt))
    if every < 1 or not math.isclose(every * dt * fps, 1.0, rel_tol=1e-9):
        raise InvalidInputError(f"fps {fps} does not divide the physics rate {1 / dt:g} Hz")
    n = len(action)
    q_out = np.empty((n, 6))
    q_out[0] = arm.joint_positions()
    if n == 1:
        return q_out
    spline = PchipInterpolator(np.arange(n) * every * dt, action[:, :6], axis=0)
    t = np.arange(1, (n - 1) * every + 1) * dt  # every step's end time
    q, qd, qdd = spline(t), spline(t, 1), spline(t, 2)
    linear_jaw = world.robot.gripper == "parallel_jaw"
    s, tick = 0, 1  # steps taken, next tick to sample
    while s < len(t):
        k = s // every + 1  # the step ends in the period (k - 1, k]
        frac = (s - (k - 1) * every + 1) / every
        cmd = (1 - frac) * action[k - 1, 6] + frac * action[k, 6] if linear_jaw else action[k, 6]
        gripper.apply_command(cmd, action[k, 7])
        before = arm.timing().steps
        try:
            arm.servo(q[s], qd[s], qdd[s])
        except ProtectiveStopError:
            # The recording met the same stop (its set-points then hold the arm where it stopped): the stop
            # held the arm for a few steps; go on from there, as the loop did after it.
            log.info("replay: protective stop at %.3f s; unlocked, replay continues", t[s])
            arm.unlock_protective_stop()
        s += arm.timing().steps - before
        while tick < n and tick * every <= s:
            q_out[tick] = arm.joint_positions()
            tick += 1
    return q_out


def replay_in_scene(scene, seed: int | None, action: np.ndarray, fps: int, camera: str | None = None):
    """Rebuild `scene` (a scene file) with `seed` as `sim.pick.run_episode` does, replay `action` in it
    (`replay_episode`) and return the (n, 6) joint positions at the ticks."""
    from prompose_grasp.pipeline.cell import make_cell
    from sim.cell import SimCellConfig
    from sim.scene_file import build_scene, load_scene

    spec = load_scene(scene)
    if camera is None:
        camera = next((c["name"] for c in spec.cameras if "pose" in c), None)
    world = build_scene(spec, seed=seed)
    with world:
        cell = make_cell(SimCellConfig(world, camera, np.random.default_rng(seed)))
        with cell:
            return replay_episode(world, cell.arm, cell.gripper, action, fps)
