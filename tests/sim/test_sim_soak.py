"""The soaks end to end on a few steps (`sim.soak`, `prompose_grasp.eval.soak`): the tracker really runs on
every played-back frame, the JSON has its fields, a bad output path is refused before any work."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from prompose_grasp.eval.soak import main as soak_main
from sim.__main__ import main as sim_main
from sim.soak import render_sweep

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def sweep():
    return render_sweep(frames=3, sweep_deg=6.0)


def test_render_sweep_moves_the_camera_along_an_arc(sweep):
    assert len(sweep) == 3
    eyes = np.array([f.T_base_cam[:3, 3] for f in sweep])
    # the same height and distance from the arc's axis, 3 degrees apart: the eye moves ~5 cm per frame at
    # ~1 m (the front camera's distance from the table's middle), not zero and not a jump
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert np.all((steps > 0.02) & (steps < 0.1))
    assert all(f.depth_m.shape == (480, 640) and np.count_nonzero(f.depth_m) > 1e5 for f in sweep)


@pytest.mark.slow
def test_soak_track_runs_the_tracker_on_every_frame(tmp_path, sweep):
    from prompose_grasp.eval.soak import soak_track
    from prompose_grasp.perception.estimator import ProMPose

    seen = []

    class Counting:
        """The real estimator; counts the frames its track pulls."""

        def __init__(self):
            self.inner = ProMPose.default()

        def track(self, frames, prompt):
            def counted():
                for f in frames:
                    seen.append(f.timestamp_s)
                    yield f

            return self.inner.track(counted(), prompt)

    r = soak_track(Counting(), sweep, "tea box", 8, warmup=2, sample_every=2, window=4)
    assert r["n_done"] == 8 and r["stopped"] is None and r["track_restarts"] == 0
    assert seen == pytest.approx([k / 30.0 for k in range(8)])  # re-stamped at 30 fps, one per step
    assert r["steps"][0]["step"] == 0 and "reinit" in r["steps"][0]  # frame 0 grounds the prompt
    assert set(r["memory"]) == {"rss", "traced"} and r["unit"] == "frame" and r["sequence_frames"] == 3
    # the box of the tea box: 12 x 8 x 7 cm in the scene file; the fit sees it within a few cm
    assert 0.03 < max(r["steps"][0]["size_m"]) < 0.2


@pytest.mark.slow
def test_library_soak_cli_plays_a_recorded_folder(tmp_path, sweep, capsys):
    folder = tmp_path / "seq"
    folder.mkdir()
    for k, f in enumerate(sweep):
        cv2.imwrite(str(folder / f"{k:06d}-color.png"), f.rgb[..., ::-1])
        cv2.imwrite(str(folder / f"{k:06d}-depth.png"), np.round(f.depth_m * 1000).astype(np.uint16))
    K = sweep[0].intrinsics
    out = tmp_path / "soak.json"
    args = ["--frames", str(folder), "--prompt", "tea box", "--intrinsics", str(K.fx), str(K.fy), str(K.cx)]
    args += [
        str(K.cy),
        "--n",
        "5",
        "--warmup",
        "1",
        "--sample-every",
        "1",
        "--window",
        "2",
        "--json",
        str(out),
    ]
    assert soak_main(args) == 0
    r = json.loads(out.read_text())
    assert r["n_done"] == 5 and len(r["samples"]) == 6 and r["frames_dir"] == str(folder)
    assert "traced slope" in capsys.readouterr().out
    assert soak_main([*args[:-1], str(tmp_path / "no" / "such.json")]) == 2  # refused before any work


@pytest.mark.slow
def test_soak_episodes_cli_runs_one_episode(tmp_path, capsys):
    out = tmp_path / "ep.json"
    code = sim_main(
        ["soak-episodes", "--episodes", "1", "--warmup", "0", "--window", "1", "--json", str(out)]
    )
    assert code == 0
    r = json.loads(out.read_text())
    assert r["n_done"] == 1 and r["unit"] == "episode" and r["scenario"] == "tabletop_household"
    step = r["steps"][0]
    assert {"seed", "command", "success", "reason", "wall_time_s"} <= set(step) and step["seed"] == 0
    assert "episodes succeeded" in capsys.readouterr().out


def test_soak_cli_refuses_an_unwritable_json_before_any_work(tmp_path, capsys):
    assert sim_main(["soak-episodes", "--json", str(tmp_path)]) == 2  # a folder, not a file
    assert "--json" in capsys.readouterr().err
