"""Grasp planning benchmark on the sim scenes: time to generate, collision-check and IK-filter 500 candidates,
and the fraction of candidates rejected per reason.

    python -m sim.bench_grasp --repeat 5 --json grasp_bench.json

Inputs are the sim's ground truth, named **oracle** here: each object's true 9-DoF box and its true mesh (as
the estimator's scaled prior would be), the supports as fixture boxes, the robot base from
`world.T_world_base`; the observed points are one rendered depth frame of the scene's first fixed camera
(with the scene's sensor noise), back-projected into `base`. This isolates grasping from perception.

For every object of a scene as the target (the others are obstacles), with `max_candidates` = 500:

- `core_ms`: candidate generation + analytic filters (stroke, support, payload, flatness) + batched
  closed-form IK + the fcl broadphase gripper check of all survivors: what "500 candidates generated,
  collision-checked and IK-filtered" means (median over `--repeat` runs);
- `plan_ms`: the whole `plan_grasps` call with a prebuilt scene: `core` + ranking + the arm-link check and the
  pre-grasp/retreat IK run lazily in rank order until 10 grasps passed;
- `scene_ms`: building the `CollisionScene` (voxelising the points, fcl objects), once per target;
- rejection fractions from one `exhaustive` run (every candidate checked to the end, arm included).

It lives in `sim` because it builds sim scenes; the library itself never imports `sim`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections import Counter
from pathlib import Path

import numpy as np

from prompose_grasp.errors import NoFeasibleGrasp
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.se3 import invert_T, transform_points
from prompose_grasp.grasp.grippers import get_gripper
from prompose_grasp.grasp.planner import build_scene, plan_grasps
from prompose_grasp.grasp.types import GraspConfig, ObjectModel, Plane
from prompose_grasp.robot import load_robot

SCENES = ("tabletop_household", "logistics_pallet")
_FIXTURE_SLAB_M = 0.03  # thickness of the slab standing in for a support's top [m]


def _support_fixtures(world, T_base_world: np.ndarray) -> list[ObjectModel]:
    """The sim's supports as fixture boxes in `base` (oracle): a slab under each surface, bin walls."""
    out = []
    for s in world.supports.values():
        if s.kind == "floor":
            continue
        T = T_base_world @ s.T_world_surface
        hx, hy = (float(v) for v in s.half_extents_xy_m)
        slab = T[:3, :3] @ np.array([0.0, 0.0, -_FIXTURE_SLAB_M / 2]) + T[:3, 3]
        extents = np.array([2 * hx, 2 * hy, _FIXTURE_SLAB_M])
        out.append(ObjectModel(f"{s.name}_top", Pose9D(T[:3, :3], slab, extents), kind="fixture"))
        if s.wall_height_m > 0:
            w, h = 0.01, float(s.wall_height_m)
            for k, (dx, dy, sx, sy) in enumerate(
                (
                    (hx + w / 2, 0, w, 2 * hy),
                    (-hx - w / 2, 0, w, 2 * hy),
                    (0, hy + w / 2, 2 * hx, w),
                    (0, -hy - w / 2, 2 * hx, w),
                )
            ):
                c = T[:3, :3] @ np.array([dx, dy, h / 2]) + T[:3, 3]
                wall = Pose9D(T[:3, :3], c, np.array([sx, sy, h]))
                out.append(ObjectModel(f"{s.name}_wall{k}", wall, kind="fixture"))
    return out


def _oracle_objects(world, T_base_world: np.ndarray) -> list[ObjectModel]:
    from sim.objects import make_object

    out = []
    for info in world.objects:
        T = T_base_world @ world.T_world_obj(info.name)
        mesh = None
        if info.source.startswith("procedural:"):
            mesh = make_object(info.category, params=info.params).mesh.copy()
            mesh.apply_transform(T)
        out.append(
            ObjectModel(
                info.name,
                Pose9D(T[:3, :3], T[:3, 3], info.size),
                mesh=mesh,
                family=info.category,
                symmetry=info.symmetry,
            )
        )
    return out


def _observed_points(world, T_base_world: np.ndarray, seed: int) -> np.ndarray:
    camera = next(n for n, c in world.cameras.items() if getattr(c, "mount", None) is None)
    frame = world.render(camera, rng=np.random.default_rng(seed))
    pts_cam = back_project(frame.depth_m, frame.intrinsics)
    return transform_points(T_base_world @ world.T_world_cam(camera), pts_cam)


def run_scene(name: str, repeat: int, seed: int) -> dict:
    from sim.scene_file import load_world

    path = Path(__file__).resolve().parent / "scenes" / f"{name}.yaml"
    world = load_world(path, seed=seed)
    kind = world.robot.gripper
    gripper = get_gripper(kind)
    robot = load_robot(world.robot.name, tcp_offset=gripper.T_flange_tcp)
    T_base_world = invert_T(world.T_world_base)
    q_home = world.robot.home_q
    objects = _oracle_objects(world, T_base_world)
    fixtures = _support_fixtures(world, T_base_world)
    points = _observed_points(world, T_base_world, seed)
    cfg = GraspConfig(max_candidates=500, suction_grid=5 if kind == "suction" else 3)
    cfg_all = GraspConfig(
        max_candidates=500, suction_grid=cfg.suction_grid, exhaustive=True, max_grasps=10_000
    )
    rows: list[dict] = []
    totals: Counter[str] = Counter()
    n_total = 0
    for target in objects:
        others = [o for o in objects if o is not target] + fixtures
        bottom = float(np.min(target.pose.corners()[:, 2]))
        support = Plane.horizontal(bottom)  # the surface the target stands on (its lowest point)
        t = time.perf_counter()
        scene = build_scene(target, robot, gripper, others, support, points, q_home, cfg)
        scene_ms = (time.perf_counter() - t) * 1e3
        core, full, cpu, n_grasps = [], [], [], 0
        for _ in range(repeat):
            t, c0 = time.perf_counter(), time.process_time()
            try:
                plan = plan_grasps(target, robot, gripper, q_seed=q_home, config=cfg, scene=scene)
                timings, n_cand, n_grasps = plan.timings_ms, plan.n_candidates, len(plan)
            except NoFeasibleGrasp as err:
                timings, n_cand = err.timings_ms, err.n_candidates
            cpu.append((time.process_time() - c0) * 1e3)
            full.append((time.perf_counter() - t) * 1e3)
            core.append(sum(timings.get(k, 0.0) for k in ("generate", "filters", "ik", "gripper_collision")))
        try:
            rejected = plan_grasps(
                target, robot, gripper, q_seed=q_home, config=cfg_all, scene=scene
            ).rejected
        except NoFeasibleGrasp as err:
            rejected = err.rejected
        totals.update(rejected)
        n_total += n_cand
        rows.append(
            {
                "target": target.name,
                "family": target.family,
                "candidates": n_cand,
                "grasps": n_grasps,
                "scene_ms": scene_ms,
                "core_ms": statistics.median(core),
                "plan_ms": statistics.median(full),
                "plan_cpu_ms": statistics.median(cpu),
                "rejected": dict(rejected),
                "voxels": len(scene.voxel_centres),
            }
        )
    world.close()
    return {
        "scene": name,
        "robot": robot.name,
        "gripper": kind,
        "objects": rows,
        "rejected_fraction": {k: v / max(n_total, 1) for k, v in sorted(totals.items())},
        "candidates": n_total,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    results = []
    for name in args.scenes:
        print(f"[{name}] loading and planning ...", flush=True)
        res = run_scene(name, args.repeat, args.seed)
        results.append(res)
        print(f"\n{name} ({res['robot']}, {res['gripper']})")
        print(f"{'target':<12} {'family':<8} {'cand':>5} {'grasps':>6} {'voxels':>6} {'scene ms':>9} "
              f"{'core ms':>8} {'plan ms':>8} {'plan CPU ms':>11}  top rejections")  # fmt: skip
        for r in res["objects"]:
            top = sorted(r["rejected"].items(), key=lambda kv: -kv[1])[:3]
            print(
                f"{r['target']:<12} {r['family']:<8} {r['candidates']:>5} {r['grasps']:>6} {r['voxels']:>6} "
                f"{r['scene_ms']:>9.1f} {r['core_ms']:>8.1f} {r['plan_ms']:>8.1f} {r['plan_cpu_ms']:>11.1f}  "
                + ", ".join(f"{k} {v}" for k, v in top)
            )
        fr = ", ".join(f"{k} {100 * v:.1f} %" for k, v in res["rejected_fraction"].items())
        print(f"rejected (of {res['candidates']} candidates, exhaustive): {fr}")
    rows = [r for res in results for r in res["objects"]]
    load_after = os.getloadavg()
    summary = {
        "targets": len(rows),
        "plan_wall_le_50ms": sum(r["plan_ms"] <= 50.0 for r in rows),
        "plan_cpu_le_50ms": sum(r["plan_cpu_ms"] <= 50.0 for r in rows),
        "core_wall_le_50ms": sum(r["core_ms"] <= 50.0 for r in rows),
        "max_plan_ms": max(r["plan_ms"] for r in rows),
        "max_plan_cpu_ms": max(r["plan_cpu_ms"] for r in rows),
        "median_plan_ms": statistics.median(r["plan_ms"] for r in rows),
        "median_plan_cpu_ms": statistics.median(r["plan_cpu_ms"] for r in rows),
        "loadavg_1_5_15_before": load_before,
        "loadavg_1_5_15_after": load_after,
        "cpus": os.cpu_count(),
    }
    print(
        f"\n{summary['plan_wall_le_50ms']} / {len(rows)} targets plan <= 50 ms wall "
        f"({summary['plan_cpu_le_50ms']} by CPU time); median plan {summary['median_plan_ms']:.1f} ms wall, "
        f"{summary['median_plan_cpu_ms']:.1f} ms CPU; max {summary['max_plan_ms']:.1f} / "
        f"{summary['max_plan_cpu_ms']:.1f} ms; load average {load_before[0]:.2f} before, {load_after[0]:.2f} "
        f"after ({os.cpu_count()} CPUs)"
    )
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "scenes": results}, indent=2))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
