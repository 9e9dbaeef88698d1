"""First-frame perception on the `bench-pick` scenes: `python -m sim.bench_perception --scenario real_meshes|
lookalikes|tabletop_household [--prompts name|colour+name] [--oracle-mask] --seeds 0-49 [--json R]`.

Each seed builds the scene `sim.bench_pick` builds for its episode (the same objects, placements, colours and
command), renders the front camera's first frame with its noise model, and asks the library's default
estimator for the command's object: grounded from the words (`ProMPose.estimate`: one object, "ambiguous" or
"not found"), or fitted on the simulator's own mask of the named object (`--oracle-mask`, ORACLE, named so:
the fit alone). No arm moves; a seed costs a scene build and one estimate, so grounding and fit changes are
measured on many scenes in minutes. Judged against the scene's ground truth:

- the outcome: `right` (the estimate's mask lies on an object the words fit, `sim.bench_accounting.
  fitting_objects`), `wrong` (on another object, or on none), `ambiguous` (correct when two or more objects
  fit the words), `not_found`; look-alike scenes also by kind (`implied` top-1, `not_implied` asked);
- for a right pick, the exact oriented-box IoU against the object's box (`eval.nocs_box_iou`) and the centre
  error; an object round about its up axis and standing on it (a family with `y_continuous` symmetry, or a
  mesh that is the same after any turn about its up axis: a cup, a bottle, a wine glass,
  `rotationally_symmetric`, read off the mesh itself) is scored NOCS-style, the best IoU over turns of the
  estimate about its y axis. A seed that is not a right pick counts as IoU 0 in 3D50 / 3D75.

The real meshes never ship with the project (licences): without ../shared/data/objects the command says so.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from prompose_grasp.errors import PromposeError
from prompose_grasp.eval.nocs import nocs_box_iou

log = logging.getLogger(__name__)

#: Turns about the up axis a rotationally symmetric mesh is tested under [deg]: not divisors of each other,
#: so a square or hexagonal footprint does not pass.
_SYMMETRY_TEST_TURNS_DEG = (23.0, 67.0, 131.0)
#: A mesh is rotationally symmetric when its turned surface stays within this share of its largest horizontal
#: extent of the original (mean nearest-neighbour distance): scans are not exactly round, 3 % of an 8 cm cup
#: is 2.4 mm; a tube of toothpaste's 4 x 5 cm oval section is 4 mm out.
_SYMMETRY_TOLERANCE = 0.03

#: An object stands on its up axis when that axis is within 15 deg of the support's normal (scans settle a
#: few degrees off where their base is uneven).
_STANDING_COS = float(np.cos(np.radians(15.0)))


def rotationally_symmetric(mesh: trimesh.Trimesh, up: int = 1, n_points: int = 3000, seed: int = 0) -> bool:
    """True when `mesh` looks the same after turns about the axis through its box centre along `up`."""
    from scipy.spatial import cKDTree

    pts = np.asarray(trimesh.sample.sample_surface(mesh, n_points, seed=seed)[0])
    centre = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
    pts = pts - centre
    tree = cKDTree(pts)
    a, b = [k for k in range(3) if k != up]
    scale = float(max(mesh.extents[a], mesh.extents[b]))
    for deg in _SYMMETRY_TEST_TURNS_DEG:
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        turned = pts.copy()
        turned[:, a], turned[:, b] = c * pts[:, a] - s * pts[:, b], s * pts[:, a] + c * pts[:, b]
        if float(np.mean(tree.query(turned)[0])) > _SYMMETRY_TOLERANCE * scale:
            return False
    return True


@cache
def _symmetric(path: str) -> bool:
    from sim.objects import load_mesh_object

    asset = load_mesh_object(path, up_axis="z")
    return rotationally_symmetric(trimesh.util.concatenate(list(asset.parts)))


def _sRT(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _which_object(mask: np.ndarray, instances: np.ndarray, names: dict[int, str]) -> str | None:
    """The scene object most of an estimate's mask lies on, or None when no object holds half of it."""
    ids, counts = np.unique(instances[mask], return_counts=True)
    if not len(ids):
        return None
    k = int(np.argmax(counts))
    if ids[k] == 0 or counts[k] < 0.5 * np.count_nonzero(mask):
        return None
    return names.get(int(ids[k]))


def perceive_one(
    scenario: str,
    seed: int,
    estimator: Any,
    prompts: str = "name",
    oracle_mask: bool = False,
    parser: Any = None,
) -> dict[str, Any]:
    """Seed `seed`'s first frame of a `bench-pick` scenario, the command's object estimated (grounded, or on
    the named object's ORACLE mask), judged against the scene's ground truth. `parser`: the loop's command
    parser (default: a new `CommandParser()`)."""
    from prompose_grasp.errors import AmbiguousObjectError, ObjectNotFoundError
    from prompose_grasp.pipeline.command import CommandParser
    from sim.bench_pick import _episode_plan
    from sim.scene_file import build_scene, load_scene

    plan = _episode_plan(scenario, seed, place=False, real_meshes=False, prompts=prompts)
    spec = load_scene(plan.scene)
    prompt = (parser or CommandParser()).parse(plan.command).object_prompt
    fitting = list(plan.fitting_objects or [])
    row: dict[str, Any] = {
        "seed": seed,
        "object": plan.target_object,
        "prompt": prompt,
        "fitting": fitting,
        "lookalike_kind": plan.lookalike_kind,
    }
    with build_scene(spec, seed=seed) as world:
        camera = next(c["name"] for c in spec.cameras if "pose" in c)
        frame = as_the_loop_sees(world, world.render(camera, rng=np.random.default_rng(seed)))
        instances = world.ground_truth_mask(camera)
        names = {o.instance_id: o.name for o in world.objects}
        gts = {g.name: g for g in world.ground_truth(camera)}
        meshes = {o.name: o.source for o in world.objects}
    # the object the command names; where the words fit several (two look-alikes), the first of them
    named = plan.target_object or fitting[0]
    row["object"] = named
    target_mask = instances == next(i for i, n in names.items() if n == named)
    row["mask_pixels"] = int(np.count_nonzero(target_mask))
    if row["mask_pixels"] < 64:  # the standard protocol's floor: too few depth pixels to evaluate
        row["status"] = "hidden"
        return row
    t0 = time.perf_counter()
    try:
        est = estimator.estimate(frame, prompt, mask=target_mask if oracle_mask else None)
    except AmbiguousObjectError as exc:
        row["status"] = "ambiguous"
        row["ambiguous"] = "correct" if len(fitting) >= 2 else "wrong"
        row["contenders"] = [_which_object(e.mask, instances, names) for e in exc.estimates]
        return row
    except ObjectNotFoundError:
        row["status"] = "not_found"
        return row
    row["time_s"] = time.perf_counter() - t0
    chosen = _which_object(est.mask, instances, names)
    row["chosen"] = chosen
    row["probability"] = float(est.probability)
    if chosen is None or chosen not in fitting:
        row["status"] = "wrong"
        return row
    gt = gts[chosen]
    plane = est.support_plane
    # round about its up axis and still standing on it (a bottle that fell over is round about a level axis)
    standing = plane is not None and abs(float(gt.R_cam_obj[:, 1] @ plane.normal_cam)) > _STANDING_COS
    if gt.symmetry != "none":
        round_about_y = gt.symmetry in ("y_continuous", "spherical")
    else:
        round_about_y = Path(meshes[chosen]).is_file() and _symmetric(meshes[chosen])
    symmetric = standing and round_about_y
    iou = nocs_box_iou(
        _sRT(est.pose.R, est.pose.t),
        np.asarray(est.pose.size),
        _sRT(gt.R_cam_obj, gt.t_cam_obj_m),
        np.asarray(gt.size_m),
        iou_mode="exact",
        y_symmetric=symmetric,
    )
    row.update(
        status="right",
        symmetric=symmetric,
        iou=float(iou),
        centre_error_m=float(np.linalg.norm(np.asarray(est.pose.t) - gt.t_cam_obj_m)),
        size_est_m=sorted((float(v) for v in est.pose.size), reverse=True),
        size_gt_m=sorted((float(v) for v in gt.size_m), reverse=True),
        prior=est.prior.name,
    )
    if plane is not None:
        up = np.asarray(plane.normal_cam, dtype=float)
        row["height_est_m"] = _extent_along(est.pose.R, est.pose.size, up)
        row["height_gt_m"] = _extent_along(gt.R_cam_obj, gt.size_m, up)
    return row


def as_the_loop_sees(world: Any, frame: Any) -> Any:
    """`frame` as the closed loop's first look has it: no depth where it sees the scene's robot
    (`grasp.self_filter.without_robot` at the arm's joints now, margin `PickConfig.self_filter_margin_m`) or
    the cell's bin (`grasp.bins.without_bins`): neither is offered as an object there, so neither is
    here."""
    from prompose_grasp.grasp import get_gripper
    from prompose_grasp.grasp.bins import without_bins
    from prompose_grasp.grasp.self_filter import without_robot
    from prompose_grasp.pipeline.config import PickConfig
    from sim.cell import place_targets_of

    if frame.T_base_cam is None:
        return frame
    info, margin = world.robot, PickConfig().self_filter_margin_m
    if info is not None and info.gripper is not None and margin is not None:
        q = world.data.qpos[info.qpos_adr].copy()
        frame = without_robot(frame, info.robot, get_gripper(info.gripper), q, margin)
    return without_bins(frame, list(place_targets_of(world).values()))


def _extent_along(R: np.ndarray, size: np.ndarray, direction: np.ndarray) -> float:
    """The extent of the box (R, size) along the unit `direction`."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    return float(np.sum(np.abs(d @ np.asarray(R)) * np.asarray(size)))


def row_line(row: dict[str, Any]) -> str:
    """One seed's result on one line."""
    head = f"seed {row['seed']:4d} {row['object']:18s} {row['status']:9s}"
    if row["status"] == "ambiguous":
        return f"{head} ({row['ambiguous']}: {', '.join(str(c) for c in row['contenders'])})"
    if row["status"] == "wrong":
        return f"{head} took {row['chosen']} (p {row['probability']:.2f})"
    if row["status"] != "right":
        return head
    est, true = np.round(row["size_est_m"], 3).tolist(), np.round(row["size_gt_m"], 3).tolist()
    height = f"{row.get('height_est_m', np.nan):.3f}/{row.get('height_gt_m', np.nan):.3f}"
    return (
        f"{head} IoU {row['iou']:.2f} centre {100 * row['centre_error_m']:.1f} cm est {est} true {true} "
        f"height {height} prior {row['prior']}"
    )


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of each outcome, and 3D50 / 3D75 [%] over the seeds (anything but a right pick counts as IoU
    0), mean and median IoU, the median centre error of the right picks; per `lookalike_kind` where the
    scenario has them: `implied` top-1 (right picks), `not_implied` asked (ambiguous, correct)."""
    scored = [r for r in rows if r["status"] != "hidden"]
    ious = np.array([r.get("iou", 0.0) for r in scored])
    centre = np.array([r["centre_error_m"] for r in scored if "centre_error_m" in r])
    n = len(scored)
    out: dict[str, Any] = {
        "n": n,
        "hidden": len(rows) - n,
        "right": sum(r["status"] == "right" for r in scored),
        "wrong": sum(r["status"] == "wrong" for r in scored),
        "ambiguous_correct": sum(r.get("ambiguous") == "correct" for r in scored),
        "ambiguous_wrong": sum(r.get("ambiguous") == "wrong" for r in scored),
        "not_found": sum(r["status"] == "not_found" for r in scored),
        "3d50": float(100.0 * np.mean(ious >= 0.5)) if n else float("nan"),
        "3d75": float(100.0 * np.mean(ious >= 0.75)) if n else float("nan"),
        "mean_iou": float(np.mean(ious)) if n else float("nan"),
        "median_iou": float(np.median(ious)) if n else float("nan"),
        "median_centre_error_cm": float(100.0 * np.median(centre)) if len(centre) else float("nan"),
    }
    for kind, good in (("implied", "right"), ("not_implied", "ambiguous_correct")):
        sub = [r for r in scored if r.get("lookalike_kind") == kind]
        if sub:
            ok = sum(
                (r["status"] == "right") if good == "right" else (r.get("ambiguous") == "correct")
                for r in sub
            )
            out[kind] = {"n": len(sub), good: ok, "wrong": sum(r["status"] == "wrong" for r in sub)}
    return out


def summary_line(s: dict[str, Any]) -> str:
    """The summary on two lines."""
    lines = [
        f"n {s['n']}: right {s['right']}, wrong {s['wrong']}, ambiguous {s['ambiguous_correct']} correct / "
        f"{s['ambiguous_wrong']} wrong, not found {s['not_found']}, hidden {s['hidden']}",
        f"3D50 {s['3d50']:.0f} %  3D75 {s['3d75']:.0f} %  mean IoU {s['mean_iou']:.3f}  median IoU "
        f"{s['median_iou']:.3f}  median centre error {s['median_centre_error_cm']:.2f} cm (right picks)",
    ]
    if "implied" in s:
        lines.append(f"implied: top-1 {s['implied']['right']}/{s['implied']['n']}")
    if "not_implied" in s:
        ni = s["not_implied"]
        lines.append(f"not implied: asked {ni['ambiguous_correct']}/{ni['n']}")
    return "\n".join(lines)


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv: list[str] | None = None) -> int:
    from sim.bench_pick import PROMPT_STYLES, SCENARIOS

    p = argparse.ArgumentParser(prog="python -m sim.bench_perception", description=__doc__.split("\n")[0])
    p.add_argument(
        "--scenario", default="real_meshes", choices=[s for s in SCENARIOS if "logistics" not in s]
    )
    p.add_argument("--prompts", default=None, choices=PROMPT_STYLES, help="default: the scenario's")
    p.add_argument("--oracle-mask", action="store_true", help="ORACLE: the named object's true mask")
    p.add_argument("--seeds", default="0-49", help="seeds, e.g. 0-49 or 100-149,200 (default 0-49)")
    p.add_argument("--json", type=Path, default=None, help="write every row and the summary here")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from prompose_grasp.perception.estimator import ProMPose
        from sim.bench_pick import _load_real_meshes, resolve_prompts

        prompts = resolve_prompts(args.scenario, args.prompts)
        if args.scenario == "real_meshes":
            _load_real_meshes()  # says where the meshes should be when they are not there
        from prompose_grasp.pipeline.command import CommandParser

        estimator, parser = ProMPose.default(), CommandParser()
        rows = []
        seeds = _seeds(args.seeds)
        for k, seed in enumerate(seeds):
            row = perceive_one(args.scenario, seed, estimator, prompts, args.oracle_mask, parser)
            rows.append(row)
            print(f"[{k + 1}/{len(seeds)}] " + row_line(row), flush=True)
    except PromposeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    summary = summarise(rows)
    mode = "oracle mask" if args.oracle_mask else "grounded"
    print(f"\n{args.scenario}, {prompts} prompts, {mode}, seeds {args.seeds}\n" + summary_line(summary))
    if args.json is not None:
        report = {"scenario": args.scenario, "prompts": prompts, "oracle_mask": args.oracle_mask}
        args.json.write_text(json.dumps({**report, "summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
