"""A `Recorder` that writes a rerun recording (extra `viz`): the only module that imports rerun.

One timeline per episode (one `PickAndPlace.run`, or one `estimate` / `track` command): "episode", then
"episode_2", ... for further runs into the same recording; its time is the wall clock since the episode
began [s]. The base frame is `world`; a camera's children are in its optical frame. The entity paths:

- world/cameras/{fixed,wrist,camera}: pose; /image pinhole, /image/rgb, /image/depth; /image/grounding
  boxes and masks of every candidate, /grounding their table; /estimates boxes, mesh, points.
- world/target/{box,mesh,points}, world/candidates, world/scene: the loop's target in base, the others.
- world/grasps/{planned,chosen,attempts/N}, grasps/plan, grasps/attempts: grasps, coloured by outcome.
- arm/joints/{planned,measured}, world/arm/{tcp,tcp_planned,tcp_measured}: the arm's commands and readings.
- gripper/{width_m,force_n,detected}, events, outcome.

docs/recording.md describes each.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from prompose_grasp._optional import require
from prompose_grasp.recorder import Recorder
from prompose_grasp.viz.target import RerunTarget

rr = require("rerun", extra="viz")

__all__ = ["RerunRecorder"]

#: Colours of an attempt by how it ended: held green, a slip orange, anything else red.
_SUCCESS, _SLIPPED, _FAILED = (40, 200, 60), (250, 150, 30), (220, 40, 40)
_ESTIMATE, _CANDIDATE, _PLANNED, _CHOSEN = (60, 220, 90), (150, 150, 150), (70, 130, 230), (250, 220, 40)
#: Scene points kept per observation: enough to see the table and the objects, ~1 MB a frame.
_MAX_SCENE_POINTS = 40_000
#: Frames remembered to find the camera a frame came from (frames come back within a few captures).
_RECENT_FRAMES = 16


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """(4,) the rotation's quaternion, x y z w (rerun's order); R re-orthonormalised by scipy."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()


def _box(pose: Any, label: str, color: tuple[int, int, int]) -> Any:
    return rr.Boxes3D(
        centers=[pose.t],
        half_sizes=[0.5 * np.asarray(pose.size)],
        quaternions=[rr.Quaternion(xyzw=_quat_xyzw(pose.R))],
        labels=[label],
        colors=[color],
    )


def _boxes(poses: list[Any], labels: list[str], color: tuple[int, int, int]) -> Any:
    return rr.Boxes3D(
        centers=[p.t for p in poses],
        half_sizes=[0.5 * np.asarray(p.size) for p in poses],
        quaternions=[rr.Quaternion(xyzw=_quat_xyzw(p.R)) for p in poses],
        labels=labels,
        colors=[color] * len(poses),
    )


def _description(attributes: Any) -> str:
    """The grounder's measured attributes in words ("red cylinder, medium, 7 x 7 x 10 cm")."""
    if attributes is None:
        return ""
    extent = " x ".join(f"{100 * v:.0f}" for v in np.asarray(attributes.extent_m))
    return f"{attributes.colour_name} {attributes.shape_family}, {attributes.size_class}, {extent} cm"


def _mask_points(frame: Any, mask: np.ndarray) -> np.ndarray:
    """(N, 3) the mask's depth readings back-projected into the camera frame [m]."""
    K = frame.intrinsics
    v, u = np.nonzero(mask & np.isfinite(frame.depth_m) & (frame.depth_m > 0))
    z = frame.depth_m[v, u].astype(np.float64)
    return np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z], axis=1)


def _subsample(points: np.ndarray, n: int) -> np.ndarray:
    points = np.asarray(points)
    return points[:: max(1, len(points) // n)]


def _gripper_lines(grasp: Any, finger_m: float = 0.05) -> list[np.ndarray]:
    """A parallel-jaw hand at the grasp as line strips (two fingers and the palm, the approach line from
    the pre-grasp); a suction cup as the approach line. Base frame [m]."""
    T = np.asarray(grasp.T_base_tcp)
    p, x, y, z = T[:3, 3], T[:3, 0], T[:3, 1], T[:3, 2]
    approach = [np.asarray(grasp.T_base_pregrasp)[:3, 3], p]
    if grasp.gripper != "parallel_jaw":
        return [np.array(approach)]
    half = 0.5 * max(float(grasp.opening_m), float(grasp.width_m))
    a, b = p + half * y, p - half * y
    hand = np.array([a + finger_m * 0.5 * z, a - finger_m * z, b - finger_m * z, b + finger_m * 0.5 * z])
    del x
    return [hand, np.array(approach)]


class RerunRecorder(Recorder):
    """Records a run into a rerun `RecordingStream` (`open` makes one for a `RerunTarget`)."""

    enabled = True

    def __init__(self, stream: Any):
        self.rec = stream
        self._timeline = ""
        self._episodes = 0
        self._t0 = time.perf_counter()
        self._recent: deque[tuple[Any, str]] = deque(maxlen=_RECENT_FRAMES)
        self._tcp_path: list[np.ndarray] = []
        self._lock = threading.Lock()
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        names = [f"joint {k + 1}" for k in range(6)]
        self.rec.log("arm/joints/planned", rr.SeriesLines(names=[f"{n} planned" for n in names]), static=True)
        self.rec.log("arm/joints/measured", rr.SeriesLines(names=names), static=True)

    @classmethod
    def open(cls, target: RerunTarget, application_id: str = "prompose_grasp") -> RerunRecorder:
        """A recorder writing to `target` (a .rrd file, whose folder is made; a spawned viewer; a URL)."""
        stream = rr.RecordingStream(application_id)
        if target.kind == "file":
            from pathlib import Path

            assert target.value is not None
            Path(target.value).parent.mkdir(parents=True, exist_ok=True)
            stream.save(target.value)
        elif target.kind == "spawn":
            stream.spawn()
        else:
            stream.connect_grpc(target.value)
        return cls(stream)

    # ------------------------------------------------------------------------------------------ time
    def begin_episode(self, name: str) -> None:
        self._episodes += 1
        self._timeline = "episode" if self._episodes == 1 else f"episode_{self._episodes}"
        self._t0 = time.perf_counter()
        self._tcp_path = []
        self._log("episode", rr.TextDocument(f"**{self._timeline}**: {name}", media_type="text/markdown"))

    def end_episode(self) -> None:
        self.rec.flush()

    def clock_s(self) -> float:
        return time.perf_counter() - self._t0

    def _log(self, path: str, *archetypes: Any, at_s: float | None = None) -> None:
        """Log at `at_s` (now when None) on the episode's timeline. The time is set in each call: rerun
        keeps it per thread, and the arm is sampled from a second thread."""
        if not self._timeline:
            self.begin_episode("estimate")
        self.rec.set_time(self._timeline, duration=self.clock_s() if at_s is None else at_s)
        self.rec.log(path, *archetypes)

    # --------------------------------------------------------------------------------------- perception
    def frame(self, camera: str, frame: Any) -> None:
        base = f"world/cameras/{camera}"
        self._recent.append((frame, base))
        K = frame.intrinsics
        if frame.T_base_cam is not None:
            T = np.asarray(frame.T_base_cam)
            self._log(base, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        pinhole = rr.Pinhole(
            image_from_camera=K.K,
            resolution=[K.width, K.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.15,
        )
        self._log(f"{base}/image", pinhole)
        self._log(f"{base}/image/rgb", rr.Image(np.asarray(frame.rgb)).compress(jpeg_quality=90))
        depth_mm = np.nan_to_num(np.asarray(frame.depth_m) * 1000.0, nan=0.0)
        self._log(
            f"{base}/image/depth", rr.DepthImage(np.clip(depth_mm, 0, 65535).astype(np.uint16), meter=1000.0)
        )

    def _camera_of(self, frame: Any) -> str:
        """The entity of the camera `frame` came from; a frame never seen is recorded as "camera"."""
        for seen, base in reversed(self._recent):
            if seen is frame:
                return base
        self.frame("camera", frame)
        return "world/cameras/camera"

    def grounding(self, frame: Any, result: Any) -> None:
        base = self._camera_of(frame)
        cands = list(result.candidates)
        path = f"{base}/image/grounding"
        if not cands:
            self._log(path, rr.Clear(recursive=True))
            self._log(f"{base}/grounding", rr.TextDocument(f"no candidate for {result.prompt!r}"))
            return
        labels = [f"#{i + 1} {c.score:.2f} {_description(c.attributes)}".strip() for i, c in enumerate(cands)]
        seg = np.zeros(np.asarray(cands[0].mask).shape, dtype=np.uint16)
        for i in reversed(range(len(cands))):  # the best candidate drawn last, on top
            seg[np.asarray(cands[i].mask)] = i + 1
        self._log(path, rr.AnnotationContext([(i + 1, labels[i]) for i in range(len(cands))]))
        self._log(f"{path}/masks", rr.SegmentationImage(seg, opacity=0.4))
        boxes = np.array([c.box_xyxy for c in cands], dtype=np.float64) + np.array(
            [0, 0, 1, 1]
        )  # inclusive -> edges
        self._log(
            f"{path}/boxes",
            rr.Boxes2D(
                array=boxes,
                array_format=rr.Box2DFormat.XYXY,
                labels=labels,
                class_ids=list(range(1, len(cands) + 1)),
            ),
        )
        rows = [
            f"| {i + 1} | {c.score:.3f} | {c.probability:.2f} | {_description(c.attributes)} | "
            f"{int(np.count_nonzero(c.mask))} |"
            for i, c in enumerate(cands)
        ]
        table = (
            f"prompt **{result.prompt}**, contenders {result.contenders}\n\n"
            "| rank | score | probability | description | pixels |\n|---|---|---|---|---|\n" + "\n".join(rows)
        )
        self._log(f"{base}/grounding", rr.TextDocument(table, media_type="text/markdown"))

    def estimates(self, frame: Any, estimates: Any) -> None:
        base = f"{self._camera_of(frame)}/estimates"
        ests = list(estimates)
        if not ests:
            self._log(base, rr.Clear(recursive=True))
            return
        labels = [f"{e.prior.name} {e.score:.2f}" for e in ests]
        self._log(f"{base}/boxes", _boxes([e.pose for e in ests], labels, _ESTIMATE))
        best = ests[0]
        mesh = best.mesh_cam
        self._log(
            f"{base}/mesh",
            rr.Mesh3D(
                vertex_positions=mesh.vertices, triangle_indices=mesh.faces, albedo_factor=[*_ESTIMATE, 120]
            ),
        )
        points = best.surface_cam if best.surface_cam is not None else _mask_points(frame, best.mask)
        self._log(
            f"{base}/points",
            rr.Points3D(_subsample(points, _MAX_SCENE_POINTS), colors=[_ESTIMATE], radii=0.002),
        )

    # ------------------------------------------------------------------------------------------- loop
    def candidates(self, observations: Any) -> None:
        obs = list(observations)
        if not obs:
            return
        first = obs[0]
        target = first.target
        self._log("world/target/box", _box(target.pose, f"target: {target.family}", _ESTIMATE))
        if target.mesh is not None:
            self._log(
                "world/target/mesh",
                rr.Mesh3D(
                    vertex_positions=target.mesh.vertices,
                    triangle_indices=target.mesh.faces,
                    albedo_factor=[*_ESTIMATE, 120],
                ),
            )
        if target.surface_points is not None:
            self._log(
                "world/target/points", rr.Points3D(target.surface_points, colors=[_ESTIMATE], radii=0.002)
            )
        others = [o.target.pose for o in obs[1:]]
        self._log(
            "world/candidates", _boxes(others, [f"candidate {k + 2}" for k in range(len(others))], _CANDIDATE)
        )
        self._log(
            "world/scene",
            rr.Points3D(
                _subsample(first.points_base, _MAX_SCENE_POINTS), colors=[(170, 170, 170)], radii=0.0015
            ),
        )

    def grasps(self, plan: Any) -> None:
        grasps = list(plan.grasps)
        if grasps:
            pre = np.array([g.T_base_pregrasp[:3, 3] for g in grasps])
            at = np.array([g.T_base_tcp[:3, 3] for g in grasps])
            shade = np.linspace(1.0, 0.35, len(grasps))[:, None]  # the best brightest
            colors = (np.array(_PLANNED)[None, :] * shade).astype(np.uint8)
            self._log(
                "world/grasps/planned", rr.Arrows3D(origins=pre, vectors=at - pre, colors=colors, radii=0.002)
            )
        rows = [
            f"| {i + 1} | {g.method} | {g.quality:.2f} | {g.score:.2f} | {100 * g.opening_m:.1f} "
            f"| {g.reason} |"
            for i, g in enumerate(grasps[:30])
        ]
        rejected = ", ".join(f"{k}: {v}" for k, v in sorted(plan.rejected.items())) or "none"
        text = (
            f"{len(grasps)} feasible of {plan.n_candidates} candidates; rejected: {rejected}\n\n"
            "| rank | method | quality | score | opening [cm] | reason |\n|---|---|---|---|---|---|\n"
            + "\n".join(rows)
        )
        self._log("grasps/plan", rr.TextDocument(text, media_type="text/markdown"))

    def grasp_tried(self, grasp: Any, index: int) -> None:
        label = f"grasp {index + 1}: {grasp.method}, quality {grasp.quality:.2f}"
        self._log(
            "world/grasps/chosen",
            rr.LineStrips3D(_gripper_lines(grasp), colors=[_CHOSEN], radii=0.003, labels=[label, ""]),
        )

    def attempt(self, record: Any) -> None:
        g = record.grasp
        color = (
            _SUCCESS if record.result == "success" else _SLIPPED if record.result == "slipped" else _FAILED
        )
        pre, at = np.asarray(g.T_base_pregrasp)[:3, 3], np.asarray(g.T_base_tcp)[:3, 3]
        self._log(
            f"world/grasps/attempts/{record.attempt}",
            rr.Arrows3D(
                origins=[pre],
                vectors=[at - pre],
                colors=[color],
                radii=0.004,
                labels=[f"attempt {record.attempt}: {record.result}"],
            ),
        )
        level = rr.TextLogLevel.INFO if record.result == "success" else rr.TextLogLevel.WARN
        text = f"attempt {record.attempt}: {record.result}: {record.message} ({g.method}: {g.reason})"
        self._log("grasps/attempts", rr.TextLog(text, level=level))
        if record.result == "success":
            self._log(
                "world/grasps/chosen", rr.LineStrips3D(_gripper_lines(g), colors=[_SUCCESS], radii=0.003)
            )

    def motion(self, name: str, t_s: Any, q: Any, tcp_xyz: Any) -> None:
        if q is not None:
            for t, qk in zip(np.asarray(t_s), np.asarray(q)):
                self._log("arm/joints/planned", rr.Scalars(qk), at_s=float(t))
        start = None if t_s is None else float(np.asarray(t_s)[0])
        self._log(
            "world/arm/tcp_planned",
            rr.LineStrips3D([np.asarray(tcp_xyz)], colors=[_PLANNED], radii=0.002, labels=[name]),
            at_s=start,
        )
        with self._lock:
            path, self._tcp_path = self._tcp_path, []
        if len(path) >= 2:
            self._log(
                "world/arm/tcp_measured", rr.LineStrips3D([np.array(path)], colors=[_SUCCESS], radii=0.002)
            )

    def arm_state(self, q: Any, T_base_tcp: Any) -> None:
        T = np.asarray(T_base_tcp)
        self._log("arm/joints/measured", rr.Scalars(np.asarray(q, dtype=np.float64)))
        self._log(
            "world/arm/tcp",
            rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
            rr.TransformAxes3D(axis_length=0.05),
        )
        with self._lock:
            self._tcp_path.append(T[:3, 3].copy())

    def gripper(
        self, width_m: float | None = None, force_n: float | None = None, detected: bool | None = None
    ) -> None:
        if width_m is not None:
            self._log("gripper/width_m", rr.Scalars([width_m]))
        if force_n is not None:
            self._log("gripper/force_n", rr.Scalars([force_n]))
        if detected is not None:
            self._log("gripper/detected", rr.Scalars([float(detected)]))

    def stage(self, stage: str, message: str) -> None:
        self._log("events", rr.TextLog(f"{stage}: {message}"))

    def outcome(self, outcome: Any) -> None:
        timings = ", ".join(f"{k} {v:.2f} s" for k, v in outcome.timings_s.items())
        attempts = "\n".join(f"- attempt {a.attempt}: {a.result}: {a.message}" for a in outcome.attempts)
        text = (
            f"**{outcome.reason}**: {outcome.message}\n\n{len(outcome.attempts)} attempt(s)\n{attempts}\n\n"
            f"timings: {timings}"
        )
        # (the loop's own "done" event already went to `events`)
        self._log("outcome", rr.TextDocument(text, media_type="text/markdown"))

    def close(self) -> None:
        """Flush and end the recording (a file gets its footer)."""
        self.rec.flush()
        self.rec.disconnect()
