"""rerun recordings (extra `viz`): `--rerun` targets are checked before any work; one seeded sim episode
recorded to a .rrd file reads back with rerun's own reader, every entity path there with the counts the
episode implies; a run without a recording never imports rerun."""

from __future__ import annotations

import collections
import os
import subprocess
import sys
from pathlib import Path

import pytest

from prompose_grasp.errors import InvalidInputError

os.environ.setdefault("MUJOCO_GL", "egl")

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "sim" / "scenes" / "tabletop_household.yaml"


def test_rerun_targets_parse_and_bad_ones_are_refused(tmp_path):
    from prompose_grasp.viz.target import RerunTarget

    assert RerunTarget.parse([str(tmp_path / "new" / "ep.rrd")]) == RerunTarget(
        "file", str(tmp_path / "new" / "ep.rrd")
    )  # a folder still to be made is fine: the recorder makes it
    assert RerunTarget.parse(["spawn"]) == RerunTarget("spawn")
    assert RerunTarget.parse(["connect"]) == RerunTarget("connect", None)
    url = "rerun+http://127.0.0.1:9876/proxy"
    assert RerunTarget.parse(["connect", url]) == RerunTarget("connect", url)
    for bad, why in [
        (["ep.txt"], "ends in .rrd"),
        ([str(tmp_path)], "ends in .rrd"),
        (["connect", "localhost"], "not a URL"),
        (["a.rrd", "b.rrd"], "takes"),
        ([], "takes"),
    ]:
        with pytest.raises(InvalidInputError, match=why):
            RerunTarget.parse(bad)


def test_the_command_lines_refuse_a_bad_target_before_any_work(tmp_path, capsys, monkeypatch):
    from prompose_grasp.cli import main
    from sim.__main__ import main as sim_main

    def refuse(*args, **kwargs):
        raise AssertionError("work started on a bad --rerun target")

    monkeypatch.setattr(subprocess, "call", refuse)  # `demo` runs the simulator as its own process
    monkeypatch.setattr("sim.pick.run_episode", refuse)
    bad = str(tmp_path / "x.txt")
    args = ["estimate", "--rgb", "none.png", "--depth", "none.png", "--intrinsics", "1", "1", "1", "1"]
    assert main([*args, "--prompt", "mug", "--rerun", bad]) == 2
    assert "ends in .rrd" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "out"), "--rerun", bad]) == 2
    assert "ends in .rrd" in capsys.readouterr().err
    pick = ["pick", "--scene", str(SCENE), "--command", "pick up the mug", "--out", str(tmp_path)]
    assert sim_main([*pick, "--rerun", "connect", "localhost"]) == 2
    assert "not a URL" in capsys.readouterr().err


def _read_back(path: Path) -> tuple[collections.Counter, set[str]]:
    """Rows per entity path and the timelines, read with rerun's own reader."""
    from rerun.chunk import RrdReader

    rows: collections.Counter = collections.Counter()
    timelines: set[str] = set()
    (store,) = RrdReader(path).recordings()
    for chunk in RrdReader(path).stream(store=store).to_chunks():
        rows[chunk.entity_path] += chunk.num_rows
        timelines.update(chunk.timeline_names)
    return rows, timelines


@pytest.mark.sim
@pytest.mark.slow
def test_a_recorded_sim_episode_reads_back_with_every_entity(tmp_path):
    pytest.importorskip("rerun", reason="rerun recordings need the extra viz")
    from prompose_grasp.viz.rerun_recorder import RerunRecorder
    from prompose_grasp.viz.target import RerunTarget
    from sim.pick import run_episode

    path = tmp_path / "episode.rrd"
    recorder = RerunRecorder.open(RerunTarget("file", str(path)))
    events: list = []
    try:
        result = run_episode(SCENE, "pick up the green bottle", None, seed=0, on_event=events.append,
                             recorder=recorder)  # fmt: skip
    finally:
        recorder.close()
    outcome = result.outcome
    assert outcome.reason == "success", outcome.message
    rows, timelines = _read_back(path)
    assert "episode" in timelines  # one timeline for the episode
    cam = "/world/cameras/fixed"
    for entity in (
        f"{cam}", f"{cam}/image", f"{cam}/image/rgb", f"{cam}/image/depth",
        f"{cam}/image/grounding/boxes", f"{cam}/image/grounding/masks", f"{cam}/grounding",
        f"{cam}/estimates/boxes", f"{cam}/estimates/mesh", f"{cam}/estimates/points",
        "/world/target/box", "/world/target/mesh", "/world/scene", "/world/grasps/planned",
        "/grasps/plan", "/world/grasps/chosen", "/world/arm/tcp", "/world/arm/tcp_planned",
        "/world/arm/tcp_measured", "/arm/joints/planned", "/arm/joints/measured", "/gripper/width_m",
        "/gripper/force_n", "/events", "/outcome",
    ):  # fmt: skip
        assert rows[entity] > 0, f"{entity} missing; recorded: {sorted(rows)}"
    # each progress event, each attempt and the outcome once; as many images as pinholes (one per frame)
    assert rows["/events"] == len(events)
    assert rows["/outcome"] == 1
    n = len(outcome.attempts)
    assert sum(v for k, v in rows.items() if k.startswith("/world/grasps/attempts/")) == n
    assert rows["/grasps/attempts"] == n
    assert rows[f"{cam}/image/rgb"] == rows[f"{cam}/image"] == rows[f"{cam}/image/depth"]
    # the arm: a planned path per command; measured joints and TCP sampled together, more often than
    # commands were sent (each command ends with a reading, and its duration adds 30 Hz samples)
    # (the joints' entity also holds one static row: the series' names)
    assert rows["/arm/joints/measured"] - 1 == rows["/world/arm/tcp"] > rows["/world/arm/tcp_planned"] >= 3
    # the example that draws a recording as a still figure runs on it (docs/recording.md's picture)
    figure = tmp_path / "episode.jpg"
    out = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "rerun_episode_figure.py"), str(path), str(figure)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    import cv2

    image = cv2.imread(str(figure))
    assert image is not None and image.shape == (990, 1920, 3)  # 2 x 3 panels of 640 x 480, a 30 px banner


@pytest.mark.sim
@pytest.mark.slow
def test_a_run_without_a_recording_does_not_import_rerun():
    # In a fresh interpreter: this test process may already hold rerun from the tests above.
    code = (
        "import sys\n"
        "from sim.pick import run_episode\n"
        f"result = run_episode({str(SCENE)!r}, 'pick up the green bottle', None, seed=0)\n"
        "assert result.outcome.reason == 'success', result.outcome.message\n"
        "print('rerun loaded' if any(m.split('.')[0] == 'rerun' for m in sys.modules) else 'no rerun')\n"
    )
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "no rerun"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Two frames of the tabletop's fixed camera (sensor noise differs), as `estimate` / `track` read them."""
    import cv2
    import numpy as np

    from prompose_grasp.hardware import write_intrinsics
    from sim.scene_file import load_world

    seq = tmp_path_factory.mktemp("seq")
    with load_world(SCENE, seed=0) as world:
        rng = np.random.default_rng(0)
        frames = [world.render("front", rng=rng) for _ in range(2)]
    for k, frame in enumerate(frames):
        cv2.imwrite(str(seq / f"{k:06d}-color.png"), frame.rgb[..., ::-1])
        depth_mm = np.clip(np.round(frame.depth_m * 1000.0), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(seq / f"{k:06d}-depth.png"), depth_mm)
    write_intrinsics(seq, frames[0].intrinsics, depth_scale_m=0.001)
    K = frames[0].intrinsics
    return seq, [str(v) for v in (K.fx, K.fy, K.cx, K.cy)]


@pytest.mark.sim
@pytest.mark.slow
def test_estimate_and_track_record_their_frames_candidates_and_estimates(sequence, tmp_path, capsys):
    pytest.importorskip("rerun", reason="rerun recordings need the extra viz")
    from prompose_grasp.cli import main

    seq, intrinsics = sequence
    frame_args = ["--intrinsics", *intrinsics, "--prompt", "green bottle"]
    est = tmp_path / "estimate.rrd"
    rgb, depth = str(seq / "000000-color.png"), str(seq / "000000-depth.png")
    assert main(["estimate", "--rgb", rgb, "--depth", depth, *frame_args, "--rerun", str(est)]) == 0
    rows, timelines = _read_back(est)
    cam = "/world/cameras/camera"  # a frame handed to the estimator directly, without a camera name
    assert "episode" in timelines
    # one frame: its image, one grounding (every candidate in one row of boxes), one set of estimates
    for entity in ("/image/rgb", "/image/depth", "/image", "/image/grounding/boxes", "/estimates/boxes"):
        assert rows[cam + entity] == 1, entity
    track = tmp_path / "track.rrd"
    assert main(["track", "--sequence", str(seq), *frame_args, "--rerun", str(track)]) == 0
    rows, _ = _read_back(track)
    # two frames, each with its estimate (the first grounded; the second a tracked update)
    assert rows[cam + "/image/rgb"] == 2
    assert rows[cam + "/estimates/boxes"] >= 2
    capsys.readouterr()
