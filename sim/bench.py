"""Benchmarks of the sim: dataset generation (frames/s) and, with --arm, physics with the arm and gripper.

    python -m sim.bench [--scenes 20] [--frames 8] [--width 640] [--height 480] [--workers 2] [--json F]
    python -m sim.bench --arm [--steps 2000] [--json F]

The dataset benchmark generates 20 scenes x 8 frames by default. The arm benchmark loads every scenario in
sim/scenes (robot and gripper built, objects settled), then measures (1) raw
physics steps per second with the arm holding its home pose and (2) a sequence of `SimArm` motions
(`move_joints` and `move_linear`): simulated time per wall-clock second of the stepping, and of the whole
commands including the IK of the straight lines. Prints a table and writes JSON with the numbers, the
settings and the machine, for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sim.dataset import DatasetConfig, generate

_SCENES = Path(__file__).parent / "scenes"


def _machine() -> dict:
    return {"cpus": os.cpu_count(), "platform": platform.platform(), "mujoco_gl": os.environ.get("MUJOCO_GL")}


def arm_benchmark(steps: int = 2000) -> dict:
    """Physics rate with the arm and gripper in every scenario, and `SimArm` motion throughput."""
    from prompose_grasp.geometry.se3 import make_T
    from sim.arm import SimArm
    from sim.scene_file import load_world

    rows = []
    for path in sorted(_SCENES.glob("*.yaml")):
        with load_world(path) as world:  # settled: a scene at rest, as a pick starts
            dt = float(world.model.opt.timestep)
            t0 = time.perf_counter()
            world.step(steps)
            wall = time.perf_counter() - t0
            with SimArm(world) as arm:
                home = arm.joint_positions()
                t0 = time.perf_counter()
                for delta in ([0.4, 0.2, -0.3, 0.2, 0.3, 0.5], [-0.4, -0.1, 0.2, -0.2, -0.3, -0.5]):
                    arm.move_joints(home + np.array(delta), 1.0, 2.0)
                T = arm.tcp_pose()
                for dz in (-0.1, 0.0):
                    arm.move_linear(make_T(T[:3, :3], T[:3, 3] + [0.0, 0.0, dz]), 0.25, 1.0)
                command_wall = time.perf_counter() - t0
                timing = arm.timing()
            rows.append(
                {
                    "scene": path.stem,
                    "robot": world.robot.name,
                    "gripper": world.robot.gripper,
                    "bodies": int(world.model.nbody),
                    "dofs": int(world.model.nv),
                    "timestep_s": dt,
                    "steps_per_s": round(steps / wall, 1),
                    "realtime_factor": round(steps * dt / wall, 2),
                    "motion_sim_s": round(timing.sim_time_s, 3),
                    "motion_realtime_factor_stepping": round(timing.realtime_factor, 2),
                    "motion_realtime_factor_with_ik": round(timing.sim_time_s / command_wall, 2),
                }
            )
    return {"benchmark": "sim arm + gripper physics", "steps": steps, "scenes": rows, "machine": _machine()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--noise", default="realsense")
    parser.add_argument("--json", default=None, help="write the result here")
    parser.add_argument("--arm", action="store_true", help="benchmark the arm and gripper physics instead")
    parser.add_argument("--steps", type=int, default=2000, help="--arm: physics steps per scene")
    args = parser.parse_args(argv)
    if args.arm:
        result = arm_benchmark(args.steps)
        print(f"{'scene':20s} {'robot':6s} {'gripper':13s} {'steps/s':>8s} {'RTF':>6s} {'moves RTF':>10s} "
              f"{'+IK RTF':>8s}")  # fmt: skip
        for r in result["scenes"]:
            print(
                f"{r['scene']:20s} {r['robot']:6s} {r['gripper']:13s} {r['steps_per_s']:8.0f} "
                f"{r['realtime_factor']:6.1f} {r['motion_realtime_factor_stepping']:10.1f} "
                f"{r['motion_realtime_factor_with_ik']:8.1f}"
            )
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(result, indent=1))
        return 0
    with tempfile.TemporaryDirectory(prefix="sim_bench_") as tmp:
        config = DatasetConfig(
            out=tmp, scenes=args.scenes, frames=args.frames, seed=0, width=args.width, height=args.height,
            noise=args.noise, workers=args.workers,
        )  # fmt: skip
        stats = generate(config, progress=True)
    result = {
        "benchmark": "sim.dataset generation",
        "scenes": args.scenes,
        "frames_per_scene": args.frames,
        "resolution": [args.width, args.height],
        "workers": args.workers,
        "noise": args.noise,
        "frames": stats["frames_written"],
        "seconds": round(stats["seconds"], 3),
        "frames_per_second": round(stats["frames_per_second"], 3),
        "machine": _machine(),
    }
    print(
        f"dataset generation: {result['frames']} frames ({args.scenes} scenes x {args.frames}) at "
        f"{args.width}x{args.height} with {args.workers} workers in {result['seconds']:.1f} s = "
        f"{result['frames_per_second']:.2f} frames/s"
    )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
