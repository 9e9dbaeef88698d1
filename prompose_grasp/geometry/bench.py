"""Benchmark of the geometry core: farthest point sampling, back-projection and exact oriented-box IoU.

    python -m prompose_grasp.geometry.bench [--repeat 7] [--json OUT.json]

Prints a table (median and best of `--repeat` runs, milliseconds) and optionally writes the same numbers as
JSON. Inputs are seeded synthetic data: a 20k-point partial object surface for FPS, a 640x480 depth image
with 10 % missing pixels for back-projection, and random overlapping oriented boxes for IoU.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np

from prompose_grasp.geometry import se3
from prompose_grasp.geometry.boxes import oriented_box_iou
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project, depth_to_point_map, farthest_point_sampling


def _time_ms(fn: Callable[[], object], repeat: int, number: int = 1) -> dict[str, float]:
    fn()  # warm-up (imports, caches)
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        runs.append((time.perf_counter() - t0) * 1e3 / number)
    return {"median_ms": statistics.median(runs), "best_ms": min(runs), "repeat": repeat, "number": number}


def _naive_fps(points: np.ndarray, n: int) -> np.ndarray:
    """The textbook float64 loop over an (N, 3) array, for comparison."""
    chosen = [0]
    nearest = np.full(len(points), np.inf)
    for _ in range(n - 1):
        nearest = np.minimum(nearest, np.sum((points - points[chosen[-1]]) ** 2, axis=1))
        chosen.append(int(np.argmax(nearest)))
    return np.array(chosen)


def run(repeat: int) -> dict[str, dict[str, float]]:
    rng = np.random.default_rng(0)
    # A partial ellipsoid surface (the visible half of an object) 0.6 m in front of the camera.
    d = rng.normal(size=(20_000, 3))
    d[:, 2] = -np.abs(d[:, 2])
    cloud = d / np.linalg.norm(d, axis=1, keepdims=True) * [0.08, 0.12, 0.05] + [0.0, 0.0, 0.6]

    cam = CameraIntrinsics(fx=615.0, fy=615.0, cx=319.5, cy=239.5, width=640, height=480)
    depth = rng.uniform(0.4, 1.5, size=(480, 640)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    mask = np.zeros(depth.shape, dtype=bool)
    mask[180:300, 260:380] = True  # a 120 x 120 object mask

    pairs = []
    for _ in range(100):
        R_a, t_a, s_a = se3.random_rotation(rng), rng.normal(scale=0.02, size=3), rng.uniform(0.05, 0.3, 3)
        R_b = R_a @ se3.so3_exp(rng.normal(scale=0.3, size=3))
        t_b, s_b = t_a + rng.normal(scale=0.02, size=3), s_a * rng.uniform(0.8, 1.2, 3)
        pairs.append((R_a, t_a, s_a, R_b, t_b, s_b))

    def all_pairs() -> None:
        for p in pairs:
            oriented_box_iou(*p)

    results = {
        "fps_20000_to_2048": _time_ms(lambda: farthest_point_sampling(cloud, 2048), repeat),
        "fps_20000_to_2048_naive_float64_reference": _time_ms(lambda: _naive_fps(cloud, 2048), 1),
        "back_project_640x480_full": _time_ms(lambda: back_project(depth, cam), repeat, number=5),
        "back_project_640x480_mask_120x120": _time_ms(
            lambda: back_project(depth, cam, mask), repeat, number=20
        ),
        "depth_to_point_map_640x480": _time_ms(lambda: depth_to_point_map(depth, cam), repeat, number=5),
    }
    iou = _time_ms(all_pairs, repeat)
    results["oriented_box_iou_per_pair"] = {
        k: (v / len(pairs) if k.endswith("_ms") else v) for k, v in iou.items()
    } | {"number": len(pairs)}
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per benchmark (default 7)")
    parser.add_argument("--json", metavar="OUT", help="also write the results as JSON to OUT")
    args = parser.parse_args(argv)
    results = run(args.repeat)
    machine = {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
        "python": platform.python_version(),
    }
    width = max(len(k) for k in results)
    print(f"{'benchmark':<{width}}  {'median ms':>10}  {'best ms':>10}")
    for name, r in results.items():
        print(f"{name:<{width}}  {r['median_ms']:>10.3f}  {r['best_ms']:>10.3f}")
    print(f"machine: {machine}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "results": results}, f, indent=2)


if __name__ == "__main__":
    main()
