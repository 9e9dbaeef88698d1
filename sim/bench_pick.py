"""Closed-loop pick-and-place success rate in MuJoCo: `python -m sim bench-pick --scenario NAME --episodes N`.

Each episode builds the scenario with its own seed (objects placed at random per seed), says one command,
runs the library's `PickAndPlace` closed loop (`sim.pick.run_episode`) and judges the result against ground
truth afterwards (the object lifted, or at the place target). The report: success rate with a Wilson 95 %
interval, a histogram of failure reasons, mean cycle time in sim seconds and in wall seconds, per episode
details; printed and written as JSON.

Scenarios (`SCENARIOS`):

- `tabletop_household`: the tabletop scene; each seed picks one of its objects at random and says
  "pick up the <prompt>" (with `--place`: "put the <prompt> in the bin");
- `logistics_pallet`: the depalletising cell; "put the brown carton on the conveyor";
- `logistics_palletise`: the palletising cell; "put the brown carton on the pallet" (the next pattern slot);
- `real_meshes` (or `--real-meshes` with the tabletop): the tabletop with 5 of the real household meshes of
  `../shared/data/objects` (geometry nothing here was tuned on) drawn per seed; fails clearly when absent.

`--oracle-mask` hands the estimator the simulator's segmentation of the target (named oracle: it replaces
grounding only; the pose fit, grasping and control are the product's): the difference to a run without it
separates perception failures from grasping failures.

Failure reasons are the `PickOutcome` reasons, plus `false_success` (the loop reported success but the object
was not lifted / not at the target in ground truth) and `crash:<exception>` (an unexpected exception).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from prompose_grasp.errors import InvalidInputError, ObjectNotFoundError

__all__ = ["SCENARIOS", "OracleMaskEstimator", "real_mesh_scene", "run_benchmark", "wilson_interval"]

log = logging.getLogger(__name__)

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
#: Where the real meshes live: ../shared/data/objects next to the repository (development data, never
#: committed).
REAL_MESHES_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "objects"
SCENARIOS = ("tabletop_household", "logistics_pallet", "logistics_palletise", "real_meshes")


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for the default z); (0, 1) when n = 0."""
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


class OracleMaskEstimator:
    """ORACLE (benchmarks only): the wrapped estimator fitted on the simulator's mask of the named object.

    `estimate` / `estimate_all` use the ground-truth segmentation of `camera` at the current simulation
    state (the frame was just captured from it) for every prompt but `place_prompt` (a place target named by
    the command, which goes to the wrapped estimator unchanged). When the target is not visible,
    ObjectNotFoundError (as the estimator).
    """

    def __init__(self, estimator: Any, world: Any, camera: str, target: str, place_prompt: str | None = None):
        self.estimator = estimator
        self.world = world
        self.camera = camera
        self.target = target
        self.place_prompt = place_prompt
        self.instance_id = next(o.instance_id for o in world.objects if o.name == target)

    def _camera_of(self, frame) -> str:
        """The scene camera whose pose is the frame's (the fixed one, or the wrist camera on the arm)."""
        if frame.T_base_cam is None:
            return self.camera
        T_world_cam = self.world.T_world_base @ np.asarray(frame.T_base_cam)
        names = [n for n in self.world.cameras if self.world.intrinsics(n).width == frame.depth_m.shape[1]]
        return min(
            names or [self.camera],
            key=lambda n: float(np.linalg.norm(self.world.T_world_cam(n)[:3, 3] - T_world_cam[:3, 3])),
        )

    def _is_target(self, prompt: str) -> bool:
        return self.place_prompt is None or prompt.strip().lower() != self.place_prompt.strip().lower()

    def estimate(self, frame, prompt, prior=None, mask=None):
        if not self._is_target(prompt):
            return self.estimator.estimate(frame, prompt, prior=prior, mask=mask)
        oracle = self.world.ground_truth_mask(self._camera_of(frame)) == self.instance_id
        if np.count_nonzero(oracle) < 50:  # a handful of pixels: hidden (e.g. lifted behind the gripper)
            raise ObjectNotFoundError(f"oracle mask: {self.target!r} is not visible")
        return self.estimator.estimate(frame, prompt, prior=prior, mask=oracle)

    def estimate_all(self, frame, prompt, prior=None, max_objects=None, min_score_ratio=0.0):
        if not self._is_target(prompt):
            return self.estimator.estimate_all(
                frame, prompt, prior=prior, max_objects=max_objects, min_score_ratio=min_score_ratio
            )
        try:
            return [self.estimate(frame, prompt, prior=prior)]
        except ObjectNotFoundError:
            return []

    def track(self, frames, prompt, prior=None):
        for frame in frames:
            yield self.estimate(frame, prompt, prior=prior)


def _load_real_meshes() -> list[dict[str, Any]]:
    index = REAL_MESHES_DIR / "objects.json"
    if not index.is_file():
        raise InvalidInputError(
            f"the real meshes are not here: {index} is missing (they live in ../shared/data/objects next to "
            "the repository and are never shipped with it); run without --real-meshes"
        )
    items = json.loads(index.read_text())
    return [o for o in items if (REAL_MESHES_DIR / o["dir"] / "model.obj").is_file()]


def real_mesh_scene(seed: int, n_objects: int = 5) -> tuple[dict[str, Any], str]:
    """The tabletop scene with `n_objects` real household meshes drawn per seed (distinct colours), and the
    prompt of the one to pick. Meshes are z-up in metres (objects.json)."""
    rng = np.random.default_rng(seed)
    items = _load_real_meshes()
    chosen = [items[i] for i in rng.choice(len(items), size=min(n_objects, len(items)), replace=False)]
    doc = yaml.safe_load((SCENES_DIR / "tabletop_household.yaml").read_text())
    palette = [
        ("red", [0.8, 0.12, 0.1, 1.0]),
        ("green", [0.1, 0.55, 0.2, 1.0]),
        ("blue", [0.15, 0.3, 0.8, 1.0]),
        ("yellow", [0.85, 0.75, 0.1, 1.0]),
        ("orange", [0.9, 0.45, 0.1, 1.0]),
        ("purple", [0.5, 0.2, 0.6, 1.0]),
    ]
    objects = []
    region = {"centre_m": [-0.15, -0.05], "half_extents_m": [0.4, 0.3]}  # the tabletop file's region
    for k, item in enumerate(chosen):
        colour, rgba = palette[k % len(palette)]
        objects.append(
            {
                "name": item["name"],
                "prompt": f"{colour} {item['prompt']}",
                "mesh": {"path": str(REAL_MESHES_DIR / item["dir"] / "model.obj"), "up_axis": "z"},
                "rgba": rgba,
                "place": {"support": "table", "region": region},
            }
        )
    doc["objects"] = objects
    doc["name"] = "tabletop_real_meshes"
    return doc, objects[int(rng.integers(len(objects)))]["prompt"]


def _episode_plan(scenario: str, seed: int, place: bool, real_meshes: bool) -> tuple[Path, str, str | None]:
    """(scene file, command, the scene object's prompt the command names or None) for one seed."""
    if scenario == "real_meshes" or real_meshes:
        doc, prompt = real_mesh_scene(seed)
        path = Path(tempfile.mkdtemp(prefix="bench_pick_")) / f"real_{seed}.yaml"
        path.write_text(yaml.safe_dump(doc))
        verb = f"put the {prompt} in the bin" if place else f"pick up the {prompt}"
        return path, verb, prompt
    path = SCENES_DIR / f"{scenario}.yaml"
    if scenario == "tabletop_household":
        doc = yaml.safe_load(path.read_text())
        prompts = [o["prompt"] for o in doc["objects"]]
        prompt = prompts[int(np.random.default_rng(seed).integers(len(prompts)))]
        return path, (f"put the {prompt} in the bin" if place else f"pick up the {prompt}"), prompt
    if scenario == "logistics_pallet":
        return path, "put the brown carton on the conveyor", None
    if scenario == "logistics_palletise":
        return path, "put the brown carton on the pallet", None
    raise InvalidInputError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")


def run_benchmark(
    scenario: str,
    episodes: int,
    seed0: int = 0,
    oracle_mask: bool = False,
    real_meshes: bool = False,
    place: bool = False,
    out_dir: str | Path | None = None,
    progress: bool = True,
    json_out: str | Path | None = None,
) -> dict[str, Any]:
    """Run `episodes` seeded episodes (seeds seed0 .. seed0 + episodes - 1) and summarise them; with
    `json_out` the report so far is rewritten after every episode (a long run can be stopped)."""
    from prompose_grasp.perception.estimator import ProMPose
    from sim.pick import run_episode

    if episodes < 1:
        raise InvalidInputError(f"episodes must be >= 1, got {episodes}")
    estimator = ProMPose.default()
    rows = []
    t_all = time.perf_counter()
    for i in range(episodes):
        seed = seed0 + i
        scene, command, _ = _episode_plan(scenario, seed, place, real_meshes)
        t0 = time.perf_counter()
        row: dict[str, Any] = {"seed": seed, "command": command}
        try:
            wrap = None
            if oracle_mask:

                def wrap(world, camera, _command=command):
                    from sim.pick import target_name_for

                    return OracleMaskEstimator(estimator, world, camera, target_name_for(world, _command))

            ep_out = None if out_dir is None else Path(out_dir) / f"episode_{seed:04d}"
            result = run_episode(
                scene, command, ep_out, seed=seed, estimator=estimator, estimator_wrapper=wrap
            )
            s = result.summary
            reason = s["outcome"]["reason"]
            if not s["success"]:
                reason = "false_success" if reason == "success" else reason
            row.update(
                success=bool(s["success"]),
                reason="success" if s["success"] else reason,
                message=s["outcome"]["message"],
                object=s["evaluation"]["object"],
                lift_height_m=s["lift_height_m"],
                inside_target=s["evaluation"].get("inside_target"),
                sim_time_s=s["sim_time_s"],
                wall_time_s=s["timings_s"]["episode_wall"],
                timings_s=s["timings_s"],
                attempts=len(s["outcome"]["attempts"]),
                attempt_results=[
                    f"{a['method']}: {a['result']} ({a['message']})" for a in s["outcome"]["attempts"]
                ],
                moved=s["evaluation"].get("moved"),
                estimate_centre_error_m=s.get("estimate_centre_error_m"),
                estimate_size_m=None if s["estimate"] is None else s["estimate"]["size"],
                ground_truth_size_m=None if s["ground_truth"] is None else s["ground_truth"]["size"],
            )
        except Exception as exc:
            log.exception("episode seed %d crashed", seed)
            row.update(
                success=False,
                reason=f"crash:{type(exc).__name__}",
                message=str(exc)[:300],
                sim_time_s=float("nan"),
                wall_time_s=time.perf_counter() - t0,
            )
        rows.append(row)
        if json_out is not None:
            partial = _summary(rows, scenario, oracle_mask, real_meshes, place, seed0, episodes, t_all)
            Path(json_out).parent.mkdir(parents=True, exist_ok=True)
            Path(json_out).write_text(json.dumps(partial, indent=2))
        if progress:
            n_ok = sum(r["success"] for r in rows)
            print(
                f"[{i + 1}/{episodes}] seed {seed} {row['reason']:18s} {command!r} "
                f"({row['wall_time_s']:.1f} s wall) -> {n_ok}/{len(rows)}",
                flush=True,
            )
    return _summary(rows, scenario, oracle_mask, real_meshes, place, seed0, episodes, t_all)


def _summary(
    rows: list[dict[str, Any]],
    scenario: str,
    oracle_mask: bool,
    real_meshes: bool,
    place: bool,
    seed0: int,
    episodes: int,
    t_all: float,
) -> dict[str, Any]:
    """The report of the episodes run so far."""
    n_ok = sum(r["success"] for r in rows)
    lo, hi = wilson_interval(n_ok, len(rows))
    sims = [r["sim_time_s"] for r in rows if math.isfinite(r.get("sim_time_s", float("nan")))]
    walls = [r["wall_time_s"] for r in rows]
    report = {
        "scenario": "real_meshes" if real_meshes else scenario,
        "oracle_mask": oracle_mask,
        "place": place,
        "episodes": len(rows),
        "episodes_planned": episodes,
        "seeds": [seed0, seed0 + len(rows) - 1],
        "successes": n_ok,
        "success_rate": n_ok / len(rows),
        "wilson95": [lo, hi],
        "reasons": dict(Counter(r["reason"] for r in rows if not r["success"])),
        "mean_cycle_sim_s": float(np.mean(sims)) if sims else None,
        "mean_cycle_wall_s": float(np.mean(walls)),
        "realtime_factor": (float(np.sum(sims)) / float(np.sum(walls))) if sims else None,
        "total_wall_s": time.perf_counter() - t_all,
        "rows": rows,
    }
    return report


def format_report(r: dict[str, Any]) -> str:
    lo, hi = r["wilson95"]
    tags = (" (oracle mask)" if r["oracle_mask"] else "") + (" (place)" if r["place"] else "")
    sim_s = r["mean_cycle_sim_s"] or float("nan")
    lines = [
        f"scenario {r['scenario']}{tags}: {r['successes']}/{r['episodes']} = "
        f"{100 * r['success_rate']:.1f} % (Wilson 95 %: {100 * lo:.1f}-{100 * hi:.1f} %), "
        f"seeds {r['seeds'][0]}-{r['seeds'][1]}",
        f"  mean cycle: {sim_s:.1f} s sim, {r['mean_cycle_wall_s']:.1f} s wall "
        f"(sim/wall {r['realtime_factor'] or float('nan'):.2f})",
        "  failures: " + (", ".join(f"{k} {v}" for k, v in sorted(r["reasons"].items())) or "none"),
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim bench-pick", description=__doc__.splitlines()[0])
    add_arguments(p)
    return run_from_args(p.parse_args(argv))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, help=f"one of {', '.join(SCENARIOS)}")
    p.add_argument("--episodes", type=int, default=20, help="seeded episodes (default 20)")
    p.add_argument("--seed0", type=int, default=0, help="first seed (default 0)")
    p.add_argument(
        "--oracle-mask", action="store_true", help="ORACLE: ground-truth mask instead of grounding"
    )
    p.add_argument(
        "--real-meshes", action="store_true", help="the tabletop with ../shared/data/objects meshes"
    )
    p.add_argument("--place", action="store_true", help="tabletop: 'put the X in the bin' instead of a pick")
    p.add_argument("--json", dest="json_out", default=None, help="write the report here")
    p.add_argument("--out", default=None, help="also write each episode's summary and overlay under DIR")


def run_from_args(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    report = run_benchmark(
        args.scenario,
        args.episodes,
        args.seed0,
        oracle_mask=args.oracle_mask,
        real_meshes=args.real_meshes,
        place=args.place,
        out_dir=args.out,
        json_out=args.json_out,
    )
    print(format_report(report))
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
