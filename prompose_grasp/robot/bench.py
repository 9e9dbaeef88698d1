"""IK benchmark: success rate, accuracy and solve time per UR model and per method.

    python -m prompose_grasp.robot.bench [--n 500] [--models ur5e ur10e] [--json OUT.json]

Protocol: targets are the flange poses of configurations drawn uniformly within the joint limits (so every
target is reachable); each solve gets an independent random in-limit seed (the "current configuration"). A
solve counts as a success only when the solver says so *and* closed-form forward kinematics of its answer is
within 1 mm and 0.1 deg of the target; a claimed success outside that is counted separately as `wrong` (it
must be 0). Unreachable targets (poses beyond the arm's reach) check that the solver fails cleanly. Times are
per solve, single thread, seeding included: CPU time of the solving thread (`time.thread_time`, immune to
other processes on a shared machine) and wall-clock time (what a caller waits, including preemption).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np

from prompose_grasp.geometry.se3 import make_T, random_rotation
from prompose_grasp.robot.ik import IKConfig, IKMethod, batch_fk_errors
from prompose_grasp.robot.model import RobotModel, load_robot
from prompose_grasp.robot.ur_models import known_robots

POSITION_TARGET_M = 1e-3
ROTATION_TARGET_RAD = np.deg2rad(0.1)


@dataclass(frozen=True)
class Variant:
    label: str
    method: IKMethod
    config: IKConfig


VARIANTS: tuple[Variant, ...] = (
    Variant("closed_form", "closed_form", IKConfig()),
    Variant("mink (closed-form seeds)", "mink", IKConfig()),
    Variant("mink, 1 seed", "mink", IKConfig(closed_form_seeds=False, max_seeds=1)),
    Variant("mink, 8 seeds", "mink", IKConfig(closed_form_seeds=False, max_seeds=8)),
    Variant("pinocchio (closed-form seeds)", "pinocchio", IKConfig()),
    Variant("pinocchio, 1 seed", "pinocchio", IKConfig(closed_form_seeds=False, max_seeds=1)),
    Variant("pinocchio, 8 seeds", "pinocchio", IKConfig(closed_form_seeds=False, max_seeds=8)),
)


def _unreachable_targets(robot: RobotModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Poses 1.2-2x the arm's reach away from the shoulder: no configuration reaches them."""
    targets = []
    shoulder = np.array([0.0, 0.0, robot.spec.d1])
    for _ in range(n):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        distance = robot.spec.reach_m * rng.uniform(1.2, 2.0)
        targets.append(make_T(random_rotation(rng), shoulder + distance * direction))
    return targets


def run_variant(robot: RobotModel, variant: Variant, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    q_true = robot.random_configurations(rng, n)
    q_seed = robot.random_configurations(rng, n)
    targets = np.stack([robot.fk(q) for q in q_true])
    Q = np.empty((n, 6))
    claimed = np.zeros(n, dtype=bool)
    times = np.empty(n)
    cpu_times = np.empty(n)
    iterations = np.empty(n)
    for i in range(n):
        cpu0 = time.thread_time()
        result = robot.ik(targets[i], q_seed=q_seed[i], method=variant.method, config=variant.config)
        cpu_times[i] = time.thread_time() - cpu0
        Q[i], claimed[i], times[i], iterations[i] = (
            result.q,
            result.success,
            result.solve_time_s,
            result.iterations,
        )
    pos, rot = batch_fk_errors(robot, Q, targets)
    within = (pos <= POSITION_TARGET_M) & (rot <= ROTATION_TARGET_RAD)
    success = claimed & within

    unreachable = _unreachable_targets(robot, np.random.default_rng(seed + 1), max(20, n // 10))
    refused = sum(not robot.ik(T, method=variant.method, config=variant.config).success for T in unreachable)
    ok_pos, ok_rot = pos[success], rot[success]
    return {
        "model": robot.name,
        "method": variant.label,
        "n": n,
        "success_rate": float(success.mean()),
        "wrong": int((claimed & ~within).sum()),
        "position_error_m_p50": float(np.median(ok_pos)) if ok_pos.size else float("nan"),
        "position_error_m_max": float(ok_pos.max()) if ok_pos.size else float("nan"),
        "rotation_error_rad_p50": float(np.median(ok_rot)) if ok_rot.size else float("nan"),
        "rotation_error_rad_max": float(ok_rot.max()) if ok_rot.size else float("nan"),
        "time_ms_p50": float(np.percentile(times, 50) * 1e3),
        "time_ms_p95": float(np.percentile(times, 95) * 1e3),
        "cpu_ms_p50": float(np.percentile(cpu_times, 50) * 1e3),
        "cpu_ms_p95": float(np.percentile(cpu_times, 95) * 1e3),
        "cpu_ms_p99": float(np.percentile(cpu_times, 99) * 1e3),
        "iterations_mean": float(iterations.mean()),
        "unreachable_refused": f"{refused}/{len(unreachable)}",
    }


def format_table(rows: list[dict]) -> str:
    header = (
        "| model | method | n | success | wrong | pos err p50 / max | rot err p50 / max "
        "| CPU time p50 / p95 / p99 "
        "| wall p50 / p95 | iters | unreachable refused |\n|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [header]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['method']} | {r['n']} | {100 * r['success_rate']:.1f} % | {r['wrong']} "
            f"| {r['position_error_m_p50']:.1e} / {r['position_error_m_max']:.1e} m "
            f"| {np.rad2deg(r['rotation_error_rad_p50']):.1e} / "
            f"{np.rad2deg(r['rotation_error_rad_max']):.1e} deg "
            f"| {r['cpu_ms_p50']:.2f} / {r['cpu_ms_p95']:.2f} / {r['cpu_ms_p99']:.2f} ms "
            f"| {r['time_ms_p50']:.2f} / {r['time_ms_p95']:.2f} ms "
            f"| {r['iterations_mean']:.1f} | {r['unreachable_refused']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n", type=int, default=500, help="reachable targets per model and method")
    parser.add_argument("--models", nargs="+", default=list(known_robots()), choices=known_robots())
    parser.add_argument(
        "--methods", nargs="+", default=[v.label for v in VARIANTS], help="subset of the variant labels"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", dest="json_path", default=None, help="write the rows here as JSON")
    args = parser.parse_args(argv)

    variants = [v for v in VARIANTS if v.label in args.methods]
    rows = []
    t0 = time.perf_counter()
    for name in args.models:
        robot = load_robot(name)
        for variant in variants:
            robot.ik(robot.fk(np.zeros(6)), method=variant.method)  # build the solver outside the timing
            rows.append(run_variant(robot, variant, args.n, args.seed))
            print(f"  {name:6s} {variant.label:32s} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    cpu = platform.processor() or platform.machine()
    machine = f"{cpu}, {platform.python_implementation()} {platform.python_version()}"
    print(f"IK benchmark, {args.n} reachable targets per row, seed {args.seed}; {machine}")
    print(format_table(rows))
    if args.json_path:
        with open(args.json_path, "w") as fh:
            json.dump({"machine": machine, "n": args.n, "seed": args.seed, "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
