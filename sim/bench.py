"""Benchmark: frames per second of synthetic dataset generation (20 scenes x 8 frames by default).

    python -m sim.bench [--scenes 20] [--frames 8] [--width 640] [--height 480] [--workers 2] [--json F]

Prints one line and writes JSON with the numbers, the settings and the machine, for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

from sim.dataset import DatasetConfig, generate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--noise", default="realsense")
    parser.add_argument("--json", default=None, help="write the result here")
    args = parser.parse_args(argv)
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
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "mujoco_gl": os.environ.get("MUJOCO_GL"),
        },
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
