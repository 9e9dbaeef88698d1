"""Soaks in the simulator: a long track and back-to-back pick episodes in one process, memory and time.

    python -m sim soak-track [--n 10000] [--prompt "tea box"] [--sequence 40] [--json OUT]
    python -m sim soak-episodes [--episodes 200] [--scenario tabletop_household] [--json OUT]

`soak-track`: the tabletop scene's fixed camera swept slowly to and fro around the table (an arc of
`--sweep-deg` azimuth over `--sequence` rendered frames, with the camera's noise model and its pose in the
arm's base frame, as a camera on a moving mount gives it), played back and forth until `--n` frames have been
tracked by `ProMPose.track` (`prompose_grasp.eval.soak.soak_track`: the tracker runs on every frame).

`soak-episodes`: what `python -m sim bench-pick --scenario S` runs per seed (`sim.bench_pick`'s episode plan,
`sim.pick.run_episode` with one shared `ProMPose`), seeds seed0 .. seed0 + N - 1, one after the other in
this process; memory sampled after every episode. Each step records the episode's verdict and wall time.

Both print the soak table (`prompose_grasp.eval.soak.format_soak`) and write the JSON report, rewritten at
every sample so a long run can be stopped and still be read.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.eval.soak import (
    add_measurement_arguments,
    check_output_path,
    format_soak,
    measurement_options,
    run_soak,
    soak_track,
    write_json,
)

__all__ = ["add_episode_arguments", "add_track_arguments", "render_sweep", "soak_episodes"]

log = logging.getLogger(__name__)

SCENES_DIR = Path(__file__).resolve().parent / "scenes"


def render_sweep(
    scene: str | Path = SCENES_DIR / "tabletop_household.yaml",
    camera: str = "front",
    frames: int = 40,
    sweep_deg: float = 24.0,
    seed: int = 0,
) -> list[Any]:
    """`frames` RGB-D frames of the scene's fixed `camera` moved along an arc of `sweep_deg` azimuth about
    the vertical through the point it looks at (the table's middle), at its own height and distance."""
    from sim.camera import look_at
    from sim.scene_file import load_world

    rng = np.random.default_rng(seed)
    out = []
    with load_world(scene, seed=seed) as world:
        T0 = world.T_world_cam(camera)
        eye = T0[:3, 3]
        # the point the camera looks at: where its optical axis meets the table's height
        axis = T0[:3, 2]
        table_z = 0.78
        target = eye + axis * (table_z - eye[2]) / axis[2]
        radial = eye[:2] - target[:2]
        for k in range(frames):
            a = math.radians(sweep_deg) * (k / max(frames - 1, 1) - 0.5)
            c, s = math.cos(a), math.sin(a)
            xy = target[:2] + np.array([c * radial[0] - s * radial[1], s * radial[0] + c * radial[1]])
            world.set_camera_pose(camera, look_at([xy[0], xy[1], eye[2]], target))
            out.append(world.render(camera, rng=rng))
    return out


def soak_episodes(
    n: int = 200,
    scenario: str = "tabletop_household",
    seed0: int = 0,
    *,
    warmup: int = 20,
    window: int = 20,
    tolerance_mib: float = 5.0,
    trace: bool = True,
    trace_frames: int = 1,
    trim: bool = False,
    progress: Any = None,
    on_sample: Any = None,
) -> dict[str, Any]:
    """`n` closed-loop episodes of `scenario` back to back (seeds seed0 ..), memory sampled after each.

    Slopes per 100 episodes; `tolerance_mib` per 100 episodes (default 5 MiB: a cell picking 1,000 times a
    day would grow 50 MiB a day)."""
    from prompose_grasp.perception.estimator import ProMPose
    from sim.bench_pick import _episode_plan
    from sim.pick import run_episode

    estimator = ProMPose.default()

    def step(i: int) -> dict[str, Any]:
        seed = seed0 + i
        plan = _episode_plan(scenario, seed, False, False, "colour+name")
        result = run_episode(
            plan.scene, plan.command, None, seed=seed, estimator=estimator, targets=plan.fitting_objects
        )
        s = result.summary
        return {
            "seed": seed,
            "command": plan.command,
            "success": bool(s["success"]),
            "reason": s["outcome"]["reason"],
            "sim_time_s": s["sim_time_s"],
            "wall_time_s": s["timings_s"]["episode_wall"],
        }

    return run_soak(
        step,
        n,
        unit="episode",
        per=100.0,
        warmup=warmup,
        sample_every=1,
        window=window,
        tolerance_mib=tolerance_mib,
        trace=trace,
        trace_frames=trace_frames,
        trim=trim,
        progress=progress,
        on_sample=on_sample,
        meta={"scenario": scenario, "seed0": seed0},
    )


def add_track_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", type=int, default=10_000, help="frames to track (default 10000)")
    p.add_argument("--prompt", default="tea box", help="the object to track (default 'tea box')")
    p.add_argument("--sequence", type=int, default=40, help="rendered frames played back and forth (40)")
    p.add_argument("--sweep-deg", type=float, default=24.0, help="azimuth the camera sweeps (24)")
    p.add_argument("--seed", type=int, default=0, help="scene and sensor-noise seed (0)")
    p.add_argument("--warmup", type=int, default=500, help="frames left out of the slopes (500)")
    p.add_argument("--sample-every", type=int, default=100, help="frames between memory samples (100)")
    p.add_argument("--window", type=int, default=500, help="frames per time window (500)")
    add_measurement_arguments(p)


def add_episode_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--episodes", type=int, default=200, help="episodes (default 200)")
    p.add_argument(
        "--scenario", default="tabletop_household", help="a bench-pick scenario (tabletop_household)"
    )
    p.add_argument("--seed0", type=int, default=0, help="first seed (0)")
    p.add_argument("--warmup", type=int, default=20, help="episodes left out of the slopes (20)")
    p.add_argument("--window", type=int, default=20, help="episodes per time window (20)")
    add_measurement_arguments(p)


def run_from_args(args: argparse.Namespace) -> int:
    check_output_path(args.json_out)
    on_sample = (lambda r: write_json(r, args.json_out)) if args.json_out else None

    def show(line: str) -> None:
        print(line, flush=True)

    if args.subcommand == "soak-track":
        from prompose_grasp.perception.estimator import ProMPose

        t0 = time.perf_counter()
        frames = render_sweep(frames=args.sequence, sweep_deg=args.sweep_deg, seed=args.seed)
        print(f"rendered {len(frames)} frames in {time.perf_counter() - t0:.1f} s; tracking {args.prompt!r}")
        report = soak_track(
            ProMPose.default(),
            frames,
            args.prompt,
            args.n,
            warmup=args.warmup,
            sample_every=args.sample_every,
            window=args.window,
            **measurement_options(args),
            progress=show,
            on_sample=on_sample,
            meta={
                "scene": "tabletop_household",
                "camera": "front",
                "sweep_deg": args.sweep_deg,
                "seed": args.seed,
            },
        )
    else:
        report = soak_episodes(
            args.episodes,
            args.scenario,
            args.seed0,
            warmup=args.warmup,
            window=args.window,
            **measurement_options(args),
            progress=show,
            on_sample=on_sample,
        )
        ok = sum(s["success"] for s in report["steps"])
        print(f"{ok}/{report['n_done']} episodes succeeded")
    print(format_soak(report))
    if args.json_out:
        write_json(report, args.json_out)
        print(f"wrote {args.json_out}")
    return 0
