"""Speed-up of the Ray fan-out over a sequential run of the same work, in one run, with identical outputs:
`python -m sim.bench_scale --workers 2 --json scale.json`.

Jobs (`--jobs`, default both):

- `dataset`: `--scenes` scenes of `--frames` frames at `--width` x `--height`, generated once one scene after
  the other in this process (the sweep's sequential executor) and once as Ray tasks on a local cluster of
  `--workers` CPUs; every file is compared byte for byte.
- `bench-pick`: `--episodes` seeded `tabletop_household` episodes, run by the sequential loop of
  `sim.bench_pick` and as Ray tasks; the reports are compared without their wall times
  (`bench_pick.deterministic_view`).

Also measured, for the scale-out estimate (`scale_out`): the local cluster's start-up, the driver's cost per
task (`--noop-tasks` empty units through the same sweep), each unit's time inside its worker, and the
first-unit warm-up of a fresh worker (its imports and, for bench-pick, its estimator). The estimate for C
cores and U units: start-up + warm-up + max(U x mean unit / C + (1 - 1/C) x longest unit, U x driver cost
per task): Graham's bound for greedy scheduling of independent units on C single-CPU slots, unless the
driver's serial dispatch is the bottleneck. It assumes the per-core speed measured here, one driver, and a
shared file system that keeps up with the writes.

The defaults (12 scenes of 6 frames at 640 x 480, 12 episodes) take about 4 minutes on 2 cores; a fresh
worker's warm-up (imports, EGL context, the estimator) is counted in the Ray time, as a real sweep pays it.

Prints a table and writes the JSON report (`--json`). Exit status 1 when the outputs differ.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import PromposeError

__all__ = ["estimate_wall_s", "main", "run_scale_benchmark"]

log = logging.getLogger(__name__)

#: The scale-out estimate's cases: (job, units), cores.
SCALE_OUT_CASES = (("dataset", 10_000), ("bench-pick", 1_000))
SCALE_OUT_CORES = (1, 2, 64, 512)


def noop_unit(payload: Any) -> int:
    """An empty unit: what the fan-out itself costs per task."""
    return 0


def estimate_wall_s(
    units: int,
    cores: int,
    unit_s: float,
    longest_unit_s: float,
    dispatch_s: float,
    startup_s: float,
    warmup_s: float,
) -> float:
    """Wall time [s] of `units` units of mean `unit_s` on `cores` single-CPU slots: Graham's list-scheduling
    bound (total work / C + (1 - 1/C) x the longest unit; exact for one core), unless the driver's serial
    dispatch (`dispatch_s` per task) takes longer; plus the cluster's start-up and a fresh worker's
    warm-up."""
    if units < 1 or cores < 1:
        raise PromposeError(f"units and cores must be >= 1, got {units}, {cores}")
    slots = min(cores, units)  # more cores than units: the spare ones idle
    compute = units * unit_s / slots + (1.0 - 1.0 / slots) * longest_unit_s
    return startup_s + warmup_s + max(compute, units * dispatch_s)


def _files(root: Path, skip: str) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != skip
    }


def _warmup_s(unit_wall_s: dict[str, float], workers: int) -> float:
    """A fresh worker's first unit minus a warm unit: the extra time of its first unit [s] (the first unit
    each worker ran is among the first `workers` to start; their excess over the median is the warm-up)."""
    times = list(unit_wall_s.values())
    if len(times) <= workers:
        return 0.0
    return max(0.0, float(np.max(times[:workers]) - np.median(times[workers:])))


def _dataset_job(args: argparse.Namespace, executor: Any, work: Path) -> dict[str, Any]:
    from prompose_grasp.eval.sweep import SequentialExecutor
    from sim.dataset import SWEEP_FILE, DatasetConfig, generate

    def config(out: Path) -> DatasetConfig:
        return DatasetConfig(out=str(out), scenes=args.scenes, frames=args.frames, seed=args.seed,
                             width=args.width, height=args.height, workers=1)  # fmt: skip

    seq = generate(config(work / "seq"), progress=False, executor=SequentialExecutor())
    par = generate(config(work / "ray"), progress=False, executor=executor)
    identical = _files(work / "seq", SWEEP_FILE) == _files(work / "ray", SWEEP_FILE) and not par["failed"]
    unit_s = list(seq["scene_wall_s"].values())
    return {
        "units": args.scenes,
        "unit": f"scene of {args.frames} frames at {args.width}x{args.height}",
        "sequential_s": seq["seconds"],
        "ray_s": par["seconds"],
        "speedup": seq["seconds"] / par["seconds"],
        "identical": identical,
        "unit_s_mean": float(np.mean(unit_s)),
        "unit_s_max": float(np.max(unit_s)),
        "ray_unit_s_mean": float(np.mean(list(par["scene_wall_s"].values()))),
        "warmup_s": _warmup_s(par["scene_wall_s"], args.workers),
        "failed": par["failed"],
    }


def _bench_pick_job(args: argparse.Namespace, executor: Any) -> dict[str, Any]:
    from sim.bench_pick import deterministic_view, run_benchmark

    t0 = time.perf_counter()
    seq = run_benchmark("tabletop_household", args.episodes, seed0=args.seed, progress=False)
    seq_s = time.perf_counter() - t0  # the estimator's loading included, as the Ray workers' is
    t0 = time.perf_counter()
    par = run_benchmark(
        "tabletop_household", args.episodes, seed0=args.seed, progress=False, executor=executor
    )
    par_s = time.perf_counter() - t0
    same = json.dumps(deterministic_view(seq), sort_keys=True) == json.dumps(
        deterministic_view(par), sort_keys=True
    )
    unit_s = [float(r["wall_time_s"]) for r in seq["rows"]]
    ray_unit_s = {str(r["seed"]): float(r.get("wall_time_s", 0.0)) for r in par["rows"]}
    return {
        "units": args.episodes,
        "unit": "tabletop_household episode",
        "sequential_s": seq_s,
        "ray_s": par_s,
        "speedup": seq_s / par_s,
        "identical": same,
        "unit_s_mean": float(np.mean(unit_s)),
        "unit_s_max": float(np.max(unit_s)),
        "ray_unit_s_mean": float(np.mean(list(ray_unit_s.values()))),
        # a fresh worker builds its estimator before its first episode: the Ray wall time beyond the units'
        "warmup_s": max(0.0, par_s - sum(ray_unit_s.values()) / args.workers),
        "success_rate": seq["success_rate"],
    }


def run_scale_benchmark(args: argparse.Namespace) -> dict[str, Any]:
    """Run the jobs sequentially and on a local Ray cluster; the report (see the module docstring)."""
    from prompose_grasp.eval.sweep import RayExecutor, Unit, run_sweep

    jobs = [j.strip() for j in args.jobs.split(",") if j.strip()]
    unknown = sorted(set(jobs) - {"dataset", "bench-pick"})
    if unknown:
        raise PromposeError(f"unknown job(s) {unknown}; known: dataset, bench-pick")
    t0 = time.perf_counter()
    executor = RayExecutor(f"local:{args.workers}")
    startup_s = time.perf_counter() - t0
    # the driver's cost per task: empty units through the same sweep (workers already started by a first pass)
    noop = [Unit(f"n{i}", i) for i in range(args.noop_tasks)]
    run_sweep(noop_unit, noop[: args.workers], executor=executor, progress=False)
    t0 = time.perf_counter()
    run_sweep(noop_unit, noop, executor=executor, progress=False)
    dispatch_s = (time.perf_counter() - t0) / max(len(noop), 1)
    report: dict[str, Any] = {
        "workers": args.workers,
        "executor": executor.describe(),
        "ray_startup_s": startup_s,
        "ray_dispatch_s_per_task": dispatch_s,
        "jobs": {},
    }
    work = Path(tempfile.mkdtemp(prefix="bench_scale_"))
    try:
        if "dataset" in jobs:
            report["jobs"]["dataset"] = _dataset_job(args, executor, work)
        if "bench-pick" in jobs:
            report["jobs"]["bench-pick"] = _bench_pick_job(args, executor)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report["scale_out"] = {
        job: {
            "units": units,
            "wall_s": {
                str(c): estimate_wall_s(
                    units, c, r["unit_s_mean"], r["unit_s_max"], dispatch_s, startup_s, r["warmup_s"]
                )
                for c in SCALE_OUT_CORES
            },
        }
        for job, units in SCALE_OUT_CASES
        if (r := report["jobs"].get(job)) is not None
    }
    return report


def format_report(report: dict[str, Any]) -> str:
    lines = [
        f"{report['executor']}: start-up {report['ray_startup_s']:.1f} s, "
        f"driver {1e3 * report['ray_dispatch_s_per_task']:.1f} ms per task",
        f"{'job':11s} {'units':>5s} {'sequential s':>12s} {'ray s':>8s} {'speed-up':>8s} {'unit s':>7s} "
        f"{'warm-up s':>9s} identical",
    ]
    for job, r in report["jobs"].items():
        lines.append(
            f"{job:11s} {r['units']:5d} {r['sequential_s']:12.1f} {r['ray_s']:8.1f} {r['speedup']:8.2f} "
            f"{r['unit_s_mean']:7.2f} {r['warmup_s']:9.1f} {'yes' if r['identical'] else 'NO'}"
        )
    for job, e in report["scale_out"].items():
        walls = ", ".join(f"{c} cores {s / 3600:.2f} h" for c, s in e["wall_s"].items())
        lines.append(f"estimate, {job} x {e['units']}: {walls}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.bench_scale", description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, default=2, help="CPUs of the local Ray cluster (default 2)")
    p.add_argument("--jobs", default="dataset,bench-pick", help="dataset, bench-pick (default both)")
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--episodes", type=int, default=12)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--noop-tasks", type=int, default=200, help="empty tasks timing the driver's cost per task"
    )
    p.add_argument("--json", dest="json_out", default=None, help="write the report here")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    for name in ("workers", "scenes", "frames", "width", "height", "episodes", "noop_tasks"):
        if getattr(args, name) < 1:
            print(f"error: --{name.replace('_', '-')} must be >= 1", file=sys.stderr)
            return 2
    try:
        report = run_scale_benchmark(args)
    except PromposeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_report(report))
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json_out}")
    return 0 if all(r["identical"] for r in report["jobs"].values()) else 1


if __name__ == "__main__":
    # run the module's own copy, so that the units Ray pickles name `sim.bench_scale`, not `__main__`
    from sim.bench_scale import main as _main

    sys.exit(_main())
