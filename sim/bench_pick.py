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
  `../shared/data/objects` (geometry nothing here was tuned on) drawn per seed, in distinct colours; fails
  clearly when absent;
- `lookalikes` (`sim.lookalikes`): 3-4 products of one kind (boxes, cans, bottles at real product sizes) and
  1-2 others; even seeds name a product the look-alikes differ from in size or colour (`implied`: pick that
  one), odd seeds a product of which there are two equal copies (`not_implied`: the right outcome is
  `ambiguous`).

`--prompts colour+name | name`: the command says the object's scene prompt with its colour ("the red
banana", default) or its bare name ("the banana"; the scene keeps its colours). `lookalikes` always says the
product's name.

`--oracle-mask` hands the estimator the simulator's segmentation of the target (named oracle: it replaces
grounding only; the pose fit, grasping and control are the product's): the difference to a run without it
separates perception failures from grasping failures.

Each row is accounted by `sim.bench_accounting.judge` (ground truth, after the run): `success`;
`wrong_object_success` (the loop reported success, another scene object was lifted / placed and not the
named one); `false_success` (the loop reported success, nothing was lifted / placed); `ambiguous`, judged
`correct` when at least two scene objects fit the words by the scenario's catalogue, else `wrong`;
`wrong_object` (the loop caught holding another object and put it back); every other `PickOutcome` reason;
`crash:<exception>` (an unexpected exception). Each row names the target object, the objects the words fit
and every scene object (name, kind, colour, size).

`--ray local:N|auto|HOST:PORT` runs each episode as a Ray task of one CPU (`prompose_grasp.eval.sweep`,
extra `cluster`; docs/scale.md); each worker process builds its own estimator once. The rows are those of a
sequential run apart from their wall times (`deterministic_view`); an episode whose worker died after its
retries is a `crash:worker_died` row. With `--json OUT`, OUT.sweep.jsonl records each finished episode and
`--resume` skips them.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from prompose_grasp.errors import InvalidInputError, ObjectNotFoundError
from sim.bench_accounting import (
    bare_name,
    describe_prompt,
    fitting_objects,
    judge,
    tally,
    tally_by_kind,
    wilson_interval,
)

__all__ = [
    "PROMPT_STYLES",
    "SCENARIOS",
    "EpisodePlan",
    "EpisodeSpec",
    "OracleMaskEstimator",
    "deterministic_view",
    "episode_unit",
    "format_report",
    "real_mesh_plan",
    "real_mesh_scene",
    "run_benchmark",
    "run_episode_row",
    "summarise",
]

log = logging.getLogger(__name__)

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
#: Where the real meshes live: ../shared/data/objects next to the repository (development data, never
#: committed).
REAL_MESHES_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "objects"
SCENARIOS = ("tabletop_household", "logistics_pallet", "logistics_palletise", "real_meshes", "lookalikes")
#: What a command says of the object: its scene prompt with the colour ("the red banana") or the bare name.
PROMPT_STYLES = ("colour+name", "name")


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


#: The real meshes' colours, in the order the drawn meshes take them (distinct within a scene).
REAL_MESH_PALETTE = (
    ("red", [0.8, 0.12, 0.1, 1.0]),
    ("green", [0.1, 0.55, 0.2, 1.0]),
    ("blue", [0.15, 0.3, 0.8, 1.0]),
    ("yellow", [0.85, 0.75, 0.1, 1.0]),
    ("orange", [0.9, 0.45, 0.1, 1.0]),
    ("purple", [0.5, 0.2, 0.6, 1.0]),
)


@dataclass
class EpisodePlan:
    """One seed's episode, by construction (ground truth for the evaluation only; the loop sees `command`).

    Attributes:
        scene: the scene file. command: what is said.
        target_object: the scene object the command names, None when the words fit several or are resolved
            by the episode's own evaluation (logistics).
        fitting_objects: every scene object the words fit (`sim.bench_accounting.fitting_objects`), None when
            known only once the scene is built (the objects of a scene file's stack).
        objects: the scene's objects with their catalogue facts {name, kind, colour, size_m, prompt, ...},
            None when they come from the built scene.
        lookalike_kind: `lookalikes` only: "implied" | "not_implied".
    """

    scene: Path
    command: str
    target_object: str | None = None
    fitting_objects: list[str] | None = None
    objects: list[dict[str, Any]] | None = None
    lookalike_kind: str | None = None


#: The facts of a scene object a row records (`scene_objects`).
_FACT_KEYS = ("name", "kind", "group", "colour", "size_m", "prompt")


def real_mesh_plan(
    seed: int, n_objects: int = 5, prompts: str = "colour+name"
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(scene document, plan) of the tabletop with `n_objects` real household meshes drawn per seed (distinct
    colours) and the one to pick. `prompts`: "colour+name" says "red banana", "name" the bare "banana"
    (objects.json's prompt); the scene's colours are the same either way. Meshes are z-up in metres."""
    rng = np.random.default_rng(seed)
    items = _load_real_meshes()
    chosen = [items[i] for i in rng.choice(len(items), size=min(n_objects, len(items)), replace=False)]
    doc = yaml.safe_load((SCENES_DIR / "tabletop_household.yaml").read_text())
    objects, facts = [], []
    region = {"centre_m": [-0.15, -0.05], "half_extents_m": [0.4, 0.3]}  # the tabletop file's region
    for k, item in enumerate(chosen):
        colour, rgba = REAL_MESH_PALETTE[k % len(REAL_MESH_PALETTE)]
        objects.append(
            {
                "name": item["name"],
                "prompt": f"{colour} {item['prompt']}",
                # the scans' own concavities (a cup's inside, a hammer's neck) in the physics, not one hull
                "mesh": {
                    "path": str(REAL_MESHES_DIR / item["dir"] / "model.obj"),
                    "up_axis": "z",
                    "collision": "decompose",
                },
                "rgba": rgba,
                "place": {"support": "table", "region": region},
            }
        )
        ex, ey, ez = (float(v) for v in item["extents_m"])  # file axes, z up
        facts.append(
            {
                "name": item["name"],
                "kind": item["prompt"],
                "colour": colour,
                "size_m": [ex, ez, ey],  # canonical: y up
                "prompt": f"{colour} {item['prompt']}",
            }
        )
    doc["objects"] = objects
    doc["name"] = "tabletop_real_meshes"
    k = int(rng.integers(len(objects)))
    said = facts[k]["prompt"] if prompts == "colour+name" else facts[k]["kind"]
    return doc, {"said": said, "target_object": facts[k]["name"], "objects": facts}


def real_mesh_scene(seed: int, n_objects: int = 5) -> tuple[dict[str, Any], str]:
    """The tabletop scene with `n_objects` real household meshes drawn per seed (distinct colours), and the
    prompt of the one to pick ("red banana"). Meshes are z-up in metres (objects.json)."""
    doc, plan = real_mesh_plan(seed, n_objects)
    return doc, plan["said"]


def resolve_prompts(scenario: str, prompts: str | None) -> str:
    """The prompt style of a run: `lookalikes` always says the product's name ("name": its commands are part
    of the scenario); the others default to "colour+name"."""
    if prompts is not None and prompts not in PROMPT_STYLES:
        raise InvalidInputError(f"unknown prompt style {prompts!r}; known: {', '.join(PROMPT_STYLES)}")
    if scenario == "lookalikes":
        if prompts == "colour+name":
            raise InvalidInputError(
                "the lookalikes scenario says the product's name only (its not_implied commands leave the "
                "colour out on purpose); run it without --prompts or with --prompts name"
            )
        return "name"
    return prompts or "colour+name"


def _temp_scene(doc: dict[str, Any], stem: str) -> Path:
    path = Path(tempfile.mkdtemp(prefix="bench_pick_")) / f"{stem}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _episode_plan(
    scenario: str, seed: int, place: bool, real_meshes: bool, prompts: str = "colour+name"
) -> EpisodePlan:
    """The scene, the command and what it means (by construction) for one seed."""

    def say(words: str) -> str:
        return f"put the {words} in the bin" if place else f"pick up the {words}"

    if scenario == "lookalikes":
        from sim.lookalikes import lookalike_scene

        doc, lp = lookalike_scene(seed)
        command = f"put the {lp['said']} in the bin" if place else lp["command"]
        return EpisodePlan(
            _temp_scene(doc, f"lookalikes_{seed}"),
            command,
            lp["target_object"],
            list(lp["fitting_objects"]),
            [{k: o[k] for k in _FACT_KEYS} for o in lp["objects"]],
            lp["lookalike_kind"],
        )
    if scenario == "real_meshes" or real_meshes:
        doc, rp = real_mesh_plan(seed, prompts=prompts)
        command = say(rp["said"])
        return EpisodePlan(
            _temp_scene(doc, f"real_{seed}"),
            command,
            rp["target_object"],
            fitting_objects(command, rp["objects"]),
            rp["objects"],
        )
    path = SCENES_DIR / f"{scenario}.yaml"
    if scenario == "tabletop_household":
        doc = yaml.safe_load(path.read_text())
        facts = []
        for o in doc["objects"]:
            colour, kind = describe_prompt(o["prompt"])
            facts.append(
                {"name": o["name"], "kind": kind, "colour": colour, "size_m": None, "prompt": o["prompt"]}
            )
        k = int(np.random.default_rng(seed).integers(len(facts)))
        words = facts[k]["prompt"] if prompts == "colour+name" else bare_name(facts[k]["prompt"])
        command = say(words)
        return EpisodePlan(path, command, facts[k]["name"], fitting_objects(command, facts), facts)
    words = "brown carton" if prompts == "colour+name" else "carton"
    if scenario == "logistics_pallet":
        return EpisodePlan(path, f"put the {words} on the conveyor")
    if scenario == "logistics_palletise":
        return EpisodePlan(path, f"put the {words} on the pallet")
    raise InvalidInputError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")


def _scene_objects(plan: EpisodePlan, evaluated: list[dict[str, Any]] | None) -> list[dict[str, Any]]:
    """Every scene object with its facts: the plan's catalogue (kind, colour) merged with the built scene's
    prompt and ground-truth size; a scene file's objects take kind and colour from their prompt."""
    known = {o["name"]: o for o in plan.objects or []}
    if not evaluated:
        return [dict(o) for o in plan.objects or []]
    out = []
    for e in evaluated:
        o = dict(known.get(e["name"], {}))
        if "kind" not in o:
            o["colour"], o["kind"] = describe_prompt(str(e.get("prompt") or e["name"]))
        o.update(name=e["name"], prompt=e.get("prompt"))
        if e.get("size_m") is not None:
            o["size_m"] = e["size_m"]
        out.append(o)
    return out


#: Row and report fields that measure the run rather than the episodes (wall-clock times, which differ between
#: any two runs, sequential or not; what executed it); every other field is a function of the episodes'
#: seeds (`deterministic_view`).
ROW_TIMING_KEYS = ("wall_time_s", "timings_s")
REPORT_TIMING_KEYS = ("total_wall_s", "mean_cycle_wall_s", "realtime_factor", "executor")


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode as a sweep unit: everything it needs, so a worker process runs it from this alone."""

    scenario: str
    seed: int
    place: bool
    real_meshes: bool
    prompts: str
    oracle_mask: bool
    out_dir: str | None = None


#: This process's estimator, built on its first episode and reused (as a sequential run reuses its one).
_ESTIMATOR: list[Any] = []


def _process_estimator() -> Any:
    if not _ESTIMATOR:
        from prompose_grasp.perception.estimator import ProMPose

        _ESTIMATOR.append(ProMPose.default())
    return _ESTIMATOR[0]


def run_episode_row(spec: EpisodeSpec, estimator: Any = None, sink: Any = None) -> dict[str, Any]:
    """Run one seeded episode and account it (`sim.bench_accounting.judge`): its report row. An unexpected
    exception becomes a `crash:<type>` row. The row depends on `spec` alone (the episode draws from its
    seed). `sink`: a `sim.record_dataset.EpisodeSink` the episode is also written into."""
    from sim.pick import run_episode

    estimator = estimator if estimator is not None else _process_estimator()
    seed = spec.seed
    plan = _episode_plan(spec.scenario, seed, spec.place, spec.real_meshes, spec.prompts)
    command = plan.command
    t0 = time.perf_counter()
    row: dict[str, Any] = {"seed": seed, "command": command, "prompts": spec.prompts}
    if plan.lookalike_kind is not None:
        row["lookalike_kind"] = plan.lookalike_kind
    row.update(
        target_object=plan.target_object,
        fitting_objects=plan.fitting_objects,
        scene_objects=_scene_objects(plan, None),
    )
    try:
        wrap = None
        if spec.oracle_mask:
            oracle_target = plan.target_object or (plan.fitting_objects or [None])[0]

            def wrap(world, camera, _command=command, _target=oracle_target):
                from sim.pick import target_name_for

                name = _target or target_name_for(world, _command)
                return OracleMaskEstimator(estimator, world, camera, name)

        ep_out = None if spec.out_dir is None else Path(spec.out_dir) / f"episode_{seed:04d}"
        targets = plan.fitting_objects or None
        result = run_episode(
            plan.scene,
            command,
            ep_out,
            seed=seed,
            estimator=estimator,
            estimator_wrapper=wrap,
            targets=targets,
            record=None if sink is None else sink.config,
        )
        s = result.summary
        ev = s["evaluation"]
        scene_objects = _scene_objects(plan, ev.get("scene_objects"))
        fitting = (
            plan.fitting_objects
            if plan.fitting_objects is not None
            else fitting_objects(command, scene_objects)
        )
        loop_reason = s["outcome"]["reason"]
        parsed = s["outcome"].get("command") or {}
        verdict = judge(
            loop_reason,
            bool(s["success"]),
            fitting,
            ev.get("lifted_objects", []),
            ev.get("placed_objects"),
            place=parsed.get("action", "pick") in ("place", "stack"),
        )
        row.update(
            success=verdict["success"],
            reason=verdict["reason"],
            loop_reason=loop_reason,
            ambiguous=verdict["ambiguous"],
            wrong_objects=verdict["wrong_objects"],
            fitting_objects=fitting,
            scene_objects=scene_objects,
            message=s["outcome"]["message"],
            object=ev["object"],
            lifted_objects=ev.get("lifted_objects"),
            placed_objects=ev.get("placed_objects"),
            lift_height_m=s["lift_height_m"],
            inside_target=ev.get("inside_target"),
            sim_time_s=s["sim_time_s"],
            wall_time_s=s["timings_s"]["episode_wall"],
            timings_s=s["timings_s"],
            attempts=len(s["outcome"]["attempts"]),
            attempt_results=[
                f"{a['method']}: {a['result']} ({a['message']})" for a in s["outcome"]["attempts"]
            ],
            moved=ev.get("moved"),
            estimate_centre_error_m=s.get("estimate_centre_error_m"),
            estimate_size_m=None if s["estimate"] is None else s["estimate"]["size"],
            ground_truth_size_m=None if s["ground_truth"] is None else s["ground_truth"]["size"],
        )
        if sink is not None:
            row["record_episode"] = sink.add(
                result.recording, command, row["success"], row["reason"], seed, str(plan.scene)
            )
    except Exception as exc:
        log.exception("episode seed %d crashed", seed)
        row.update(
            success=False,
            reason=f"crash:{type(exc).__name__}",
            loop_reason=None,
            ambiguous=None,
            message=str(exc)[:300],
            sim_time_s=float("nan"),
            wall_time_s=time.perf_counter() - t0,
        )
    return row


def episode_unit(spec: EpisodeSpec) -> dict[str, Any]:
    """`run_episode_row` as a sweep unit (`prompose_grasp.eval.sweep`), with this process's estimator."""
    return run_episode_row(spec)


def failure_row(spec: EpisodeSpec, failure: Any) -> dict[str, Any]:
    """The row of an episode whose unit failed after its retries (`sweep.UnitFailure`: its worker died, or
    something outside the episode raised): a `crash:<error>` row, counted as a failure."""
    plan = _episode_plan(spec.scenario, spec.seed, spec.place, spec.real_meshes, spec.prompts)
    return {
        "seed": spec.seed,
        "command": plan.command,
        "prompts": spec.prompts,
        "target_object": plan.target_object,
        "fitting_objects": plan.fitting_objects,
        "success": False,
        "reason": f"crash:{failure.error}",
        "loop_reason": None,
        "ambiguous": None,
        "message": failure.message,
        "sim_time_s": float("nan"),
        "unit_attempts": failure.attempts,
    }


def deterministic_view(report: dict[str, Any]) -> dict[str, Any]:
    """The report without its wall-clock fields (`ROW_TIMING_KEYS`, `REPORT_TIMING_KEYS`): what two runs of
    the same seeds agree on, whatever ran them."""
    out = {k: v for k, v in report.items() if k not in REPORT_TIMING_KEYS and k != "rows"}
    out["rows"] = [{k: v for k, v in r.items() if k not in ROW_TIMING_KEYS} for r in report.get("rows", [])]
    return out


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
    prompts: str | None = None,
    ray: str | None = None,
    resume: bool = False,
    retries: int = 2,
    executor: Any = None,
    record: str | Path | None = None,
    record_config: Any = None,
) -> dict[str, Any]:
    """Run `episodes` seeded episodes (seeds seed0 .. seed0 + episodes - 1) and summarise them; with
    `json_out` the report so far is rewritten after every episode (a long run can be stopped).

    `record`: also write every episode into a new LeRobot dataset there (`sim.record_dataset`; the command as
    its task, success and reason per episode), sampled with `record_config` (`sim.recording.RecordConfig`).

    `prompts`: "colour+name" (default; "pick up the red banana") or "name" (the bare object name, "pick up
    the banana"; the scene keeps its colours); `lookalikes` always says the product's name.

    `ray` (a `--ray` value), `executor` (a `prompose_grasp.eval.sweep` executor) or `resume` run the
    episodes as sweep units (`_run_sweep`); the rows are the same as this process's loop gives."""
    if episodes < 1:
        raise InvalidInputError(f"episodes must be >= 1, got {episodes}")
    if scenario not in SCENARIOS:
        raise InvalidInputError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
    style = resolve_prompts("real_meshes" if real_meshes else scenario, prompts)
    sweep = ray is not None or executor is not None or resume
    if record is not None and sweep:
        # the dataset is one writer's files: record a shard per process (different --seed0) instead
        raise InvalidInputError(
            "--record writes the dataset from this process: run recorded shards without --ray / --resume"
        )
    sink = None
    if record is not None:
        from sim.record_dataset import EpisodeSink

        sink = EpisodeSink(record, record_config)  # checks the folder before the estimator loads
    meta = {
        "scenario": "real_meshes" if real_meshes else scenario,
        "oracle_mask": oracle_mask,
        "place": place,
        "prompts": style,
        "seed0": seed0,
        "episodes": episodes,
    }
    specs = [
        EpisodeSpec(scenario, seed0 + i, place, real_meshes, style, oracle_mask,
                    None if out_dir is None else str(out_dir))
        for i in range(episodes)
    ]  # fmt: skip
    if sweep:
        return _run_sweep(specs, meta, json_out, progress, ray, resume, retries, executor)
    from prompose_grasp.perception.estimator import ProMPose

    estimator = ProMPose.default()  # one per run, as before the sweep existed
    rows = []
    t_all = time.perf_counter()
    for i, spec in enumerate(specs):
        row = run_episode_row(spec, estimator, sink)
        rows.append(row)
        if json_out is not None:
            partial = summarise(rows, meta, time.perf_counter() - t_all)
            Path(json_out).parent.mkdir(parents=True, exist_ok=True)
            Path(json_out).write_text(json.dumps(partial, indent=2))
        if progress:
            n_ok = sum(r["success"] for r in rows)
            print(
                f"[{i + 1}/{episodes}] seed {spec.seed} {row['reason']:20s} {row['command']!r} "
                f"({row['wall_time_s']:.1f} s wall) -> {n_ok}/{len(rows)}",
                flush=True,
            )
    report = summarise(rows, meta, time.perf_counter() - t_all)
    if sink is not None:
        sink.close()
        report["record"] = {"root": str(sink.root), "episodes": sink.num_episodes}
    return report


def sweep_file(json_out: str | Path) -> Path:
    """The resume file of a sweep-run bench next to its report: OUT.json -> OUT.sweep.jsonl."""
    p = Path(json_out)
    return p.with_name(p.stem + ".sweep.jsonl")


def _run_sweep(specs, meta, json_out, progress, ray, resume, retries, executor) -> dict[str, Any]:
    from prompose_grasp.eval.sweep import Unit, make_executor, run_sweep

    if resume and json_out is None:
        raise InvalidInputError(
            "--resume needs --json OUT: the finished episodes are kept in OUT.sweep.jsonl"
        )
    executor = executor or make_executor(ray)
    units = [Unit(f"seed_{spec.seed:06d}", spec) for spec in specs]
    # one episode: MuJoCo physics and rendering and the estimator's torch, each single-threaded
    sweep = run_sweep(
        episode_unit,
        units,
        executor=executor,
        num_cpus=1,
        retries=retries,
        resume_file=None if json_out is None else sweep_file(json_out),
        resume=resume,
        progress=progress,
        label="episodes",
    )
    rows = [
        sweep.results[u.id] if u.id in sweep.results else failure_row(u.payload, sweep.failures[u.id])
        for u in units
    ]
    report = summarise(rows, meta, sweep.wall_s)
    report["executor"] = sweep.executor
    return report


def summarise(rows: list[dict[str, Any]], meta: dict[str, Any], total_wall_s: float = 0.0) -> dict[str, Any]:
    """The report of the (accounted) rows run so far; `meta`: scenario, oracle_mask, place, prompts, seed0,
    episodes (planned). Pure: the tests feed it hand-built rows."""
    n = len(rows)
    n_ok = sum(bool(r["success"]) for r in rows)
    lo, hi = wilson_interval(n_ok, n)
    sims = [r["sim_time_s"] for r in rows if math.isfinite(r.get("sim_time_s", float("nan")))]
    walls = [r["wall_time_s"] for r in rows if "wall_time_s" in r]
    seed0 = int(meta.get("seed0", 0))
    counts = tally(rows)
    report = {
        "scenario": meta.get("scenario"),
        "oracle_mask": bool(meta.get("oracle_mask", False)),
        "place": bool(meta.get("place", False)),
        "prompts": meta.get("prompts", "colour+name"),
        "episodes": n,
        "episodes_planned": int(meta.get("episodes", n)),
        "seeds": [seed0, seed0 + n - 1],
        "successes": n_ok,
        "success_rate": n_ok / n if n else 0.0,
        "wilson95": [lo, hi],
        **counts,
        "by_kind": tally_by_kind(rows),
        "mean_cycle_sim_s": float(np.mean(sims)) if sims else None,
        "mean_cycle_wall_s": float(np.mean(walls)) if walls else None,
        "realtime_factor": (float(np.sum(sims)) / float(np.sum(walls))) if sims and walls else None,
        "total_wall_s": total_wall_s,
        "rows": rows,
    }
    return report


def _pct(entry: dict[str, Any]) -> str:
    lo, hi = entry["wilson95"]
    rate = entry["rate"]
    return f"{100 * (rate or 0.0):.0f} % (Wilson 95 %: {100 * lo:.0f}-{100 * hi:.0f} %)"


def format_report(r: dict[str, Any]) -> str:
    """The printed summary; the first line carries the success rate and the wrong-object successes."""
    lo, hi = r["wilson95"]
    tags = (" (oracle mask)" if r["oracle_mask"] else "") + (" (place)" if r["place"] else "")
    tags += f" [prompts {r.get('prompts', 'colour+name')}]"
    sim_s = r["mean_cycle_sim_s"] or float("nan")
    amb = r["ambiguous"]
    lines = [
        f"scenario {r['scenario']}{tags}: {r['successes']}/{r['episodes']} = "
        f"{100 * r['success_rate']:.1f} % (Wilson 95 %: {100 * lo:.1f}-{100 * hi:.1f} %), "
        f"wrong-object successes {r['wrong_object_success']}, seeds {r['seeds'][0]}-{r['seeds'][1]}",
        f"  ambiguous {amb['total']} (correct {amb['correct']}, wrong {amb['wrong']}); wrong_object (caught, "
        f"put back) {r['wrong_object']}; false_success {r['false_success']}",
        "  other failures: " + (", ".join(f"{k} {v}" for k, v in r["other_failures"].items()) or "none"),
    ]
    for kind, e in r.get("by_kind", {}).items():
        if kind == "implied":
            lines.append(
                f"  implied ({e['episodes']}): top-1 {e['top1']['count']}/{e['episodes']} = "
                f"{_pct(e['top1'])}; "
                f"wrong picks {e['wrong_pick']['count']}/{e['episodes']}; ambiguous {e['ambiguous']}"
            )
        else:
            lines.append(
                f"  not_implied ({e['episodes']}): ambiguous {e['ambiguous']['count']}/{e['episodes']} = "
                f"{_pct(e['ambiguous'])}; picked one without asking {e['picked_one']}; "
                f"wrong picks {e['wrong_pick']['count']}/{e['episodes']}"
            )
    if r["mean_cycle_wall_s"] is not None:
        lines.append(
            f"  mean cycle: {sim_s:.1f} s sim, {r['mean_cycle_wall_s']:.1f} s wall "
            f"(sim/wall {r['realtime_factor'] or float('nan'):.2f})"
        )
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
    p.add_argument(
        "--prompts",
        choices=PROMPT_STYLES,
        default=None,
        help="what the command says: colour+name ('the red banana', default) or name ('the banana'; the "
        "scene keeps its colours); lookalikes always says the product name",
    )
    p.add_argument("--json", dest="json_out", default=None, help="write the report here")
    p.add_argument("--out", default=None, help="also write each episode's summary and overlay under DIR")
    p.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="run the episodes as Ray tasks: local:N (a local cluster of N CPUs), auto (the cluster of "
        "`ray start`), or HOST:PORT (extra `cluster`; docs/scale.md)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="skip the episodes that JSON.sweep.jsonl lists as done (needs --json)",
    )
    p.add_argument("--retries", type=int, default=2, help="attempts after the first for a failed episode")
    add_record_arguments(p)


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record DIR, --record-fps, --record-size (`sim.record_dataset`)."""
    p.add_argument(
        "--record",
        default=None,
        metavar="DIR",
        help="also write the episodes as a LeRobot v3.0 dataset into DIR (a new folder): front and wrist "
        "video, joints, TCP pose, gripper state, commanded actions, the command as task, success and reason",
    )
    p.add_argument("--record-fps", type=int, default=20, help="recording control rate [Hz] (default 20)")
    p.add_argument("--record-size", default="160x120", help="recorded image size WxH (default 160x120)")


def record_config_from_args(args: argparse.Namespace):
    """The `RecordConfig` of --record-fps / --record-size, or None without --record."""
    if getattr(args, "record", None) is None:
        return None
    from sim.recording import RecordConfig

    try:
        w, h = (int(v) for v in str(args.record_size).lower().split("x"))
    except ValueError:
        raise InvalidInputError(f"--record-size must be WxH like 160x120, got {args.record_size!r}") from None
    return RecordConfig(fps=args.record_fps, width=w, height=h)


def run_from_args(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if getattr(args, "ray", None) is not None:
        from prompose_grasp.eval.sweep import parse_ray_address

        parse_ray_address(args.ray)  # a bad --ray fails before any episode
    if getattr(args, "retries", 0) < 0:
        raise InvalidInputError(f"--retries must be >= 0, got {args.retries}")
    if getattr(args, "resume", False) and not args.json_out:
        raise InvalidInputError(
            "--resume needs --json OUT: the finished episodes are kept in OUT.sweep.jsonl"
        )
    report = run_benchmark(
        args.scenario,
        args.episodes,
        args.seed0,
        oracle_mask=args.oracle_mask,
        real_meshes=args.real_meshes,
        place=args.place,
        out_dir=args.out,
        json_out=args.json_out,
        prompts=getattr(args, "prompts", None),
        ray=getattr(args, "ray", None),
        resume=getattr(args, "resume", False),
        retries=getattr(args, "retries", 2),
        record=getattr(args, "record", None),
        record_config=record_config_from_args(args),
    )
    print(format_report(report))
    if report.get("record"):
        print(f"recorded {report['record']['episodes']} episodes into {report['record']['root']}")
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
