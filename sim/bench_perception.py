"""The 9-DoF fit alone on the real household meshes: `python -m sim.bench_fit_meshes --seeds 0-49 [--json R]`.

Each seed builds the `real_meshes` tabletop of `sim.bench_pick` (five of the ../shared meshes, placed and
settled by the physics, random colours), renders the front camera's first frame with its noise model and
fits the named object on the simulator's own mask of it (the ORACLE mask, named so: it isolates the fit from
grounding) with the library's default estimator and the bare name as the prompt. Scored against the mesh's
ground-truth box (its axis-aligned box in the file's frame, turned by the settled pose):

- exact oriented-box IoU (`eval.nocs_box_iou`); a mesh that is the same after any turn about its up axis (a
  cup, a bottle, a wine glass: `rotationally_symmetric`, read off the mesh itself) and stands on it is scored
  NOCS-style, the best IoU over turns of the estimate about its y axis;
- the centre error, and the estimated extents against the true ones (both sorted, so a box whose axes are
  named differently is compared extent by extent).

The meshes never ship with the project (licences): without ../shared/data/objects the command says so.
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


def fit_one(seed: int, estimator: Any) -> dict[str, Any]:
    """Build seed `seed`'s real-mesh scene, fit its named object on the oracle mask, score it."""
    from prompose_grasp.errors import AmbiguousObjectError, ObjectNotFoundError
    from sim.bench_pick import _temp_scene, real_mesh_plan
    from sim.scene_file import build_scene, load_scene

    doc, plan = real_mesh_plan(seed, prompts="name")
    spec = load_scene(_temp_scene(doc, f"fit_{seed}"))
    name = plan["target_object"]
    mesh_path = next(o["mesh"]["path"] for o in doc["objects"] if o["name"] == name)
    row: dict[str, Any] = {"seed": seed, "object": name, "prompt": f"the {plan['said']}"}
    with build_scene(spec, seed=seed) as world:
        camera = next(c["name"] for c in spec.cameras if "pose" in c)
        frame = world.render(camera, rng=np.random.default_rng(seed))
        obj = next(o for o in world.objects if o.name == name)
        mask = world.ground_truth_mask(camera) == obj.instance_id
        gt = next(g for g in world.ground_truth(camera) if g.name == name)
    row["mask_pixels"] = int(np.count_nonzero(mask))
    if row["mask_pixels"] < 64:  # the standard protocol's floor: too few depth pixels to evaluate
        row["status"] = "hidden"
        return row
    t0 = time.perf_counter()
    try:
        est = estimator.estimate(frame, row["prompt"], mask=mask)
    except (ObjectNotFoundError, AmbiguousObjectError) as exc:
        row["status"] = type(exc).__name__
        return row
    row["fit_s"] = time.perf_counter() - t0
    # round about its up axis and still standing on it (a bottle that fell over is round about a level axis)
    plane = est.support_plane
    standing = plane is not None and abs(float(gt.R_cam_obj[:, 1] @ plane.normal_cam)) > _STANDING_COS
    symmetric = standing and _symmetric(mesh_path)
    iou = nocs_box_iou(
        _sRT(est.pose.R, est.pose.t),
        np.asarray(est.pose.size),
        _sRT(gt.R_cam_obj, gt.t_cam_obj_m),
        np.asarray(gt.size_m),
        iou_mode="exact",
        y_symmetric=symmetric,
    )
    row.update(
        status="ok",
        symmetric=symmetric,
        iou=float(iou),
        centre_error_m=float(np.linalg.norm(np.asarray(est.pose.t) - gt.t_cam_obj_m)),
        size_est_m=sorted((float(v) for v in est.pose.size), reverse=True),
        size_gt_m=sorted((float(v) for v in gt.size_m), reverse=True),
        prior=est.prior.name,
    )
    if est.support_plane is not None:
        up = np.asarray(est.support_plane.normal_cam, dtype=float)
        row["height_est_m"] = _extent_along(est.pose.R, est.pose.size, up)
        row["height_gt_m"] = _extent_along(gt.R_cam_obj, gt.size_m, up)
    return row


def _extent_along(R: np.ndarray, size: np.ndarray, direction: np.ndarray) -> float:
    """The extent of the box (R, size) along the unit `direction`."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    return float(np.sum(np.abs(d @ np.asarray(R)) * np.asarray(size)))


def row_line(row: dict[str, Any]) -> str:
    """One seed's result on one line."""
    head = f"seed {row['seed']:4d} {row['object']:16s} {row['status']:8s}"
    if row["status"] != "ok":
        return head
    est, true = np.round(row["size_est_m"], 3).tolist(), np.round(row["size_gt_m"], 3).tolist()
    height = f"{row.get('height_est_m', np.nan):.3f}/{row.get('height_gt_m', np.nan):.3f}"
    return (
        f"{head} IoU {row['iou']:.2f} centre {100 * row['centre_error_m']:.1f} cm est {est} true {true} "
        f"height {height} prior {row['prior']}"
    )


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """3D50 / 3D75 [%] over the seeds (a failed fit counts as IoU 0), mean and median IoU, centre error."""
    scored = [r for r in rows if r["status"] != "hidden"]
    ious = np.array([r.get("iou", 0.0) for r in scored])
    centre = np.array([r["centre_error_m"] for r in scored if "centre_error_m" in r])
    n = len(scored)
    return {
        "n": n,
        "3d50": float(100.0 * np.mean(ious >= 0.5)) if n else float("nan"),
        "3d75": float(100.0 * np.mean(ious >= 0.75)) if n else float("nan"),
        "mean_iou": float(np.mean(ious)) if n else float("nan"),
        "median_iou": float(np.median(ious)) if n else float("nan"),
        "median_centre_error_cm": float(100.0 * np.median(centre)) if len(centre) else float("nan"),
        "hidden": len(rows) - n,
    }


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.bench_fit_meshes", description=__doc__.split("\n")[0])
    p.add_argument("--seeds", default="0-49", help="seeds, e.g. 0-49 or 100-149,200 (default 0-49)")
    p.add_argument("--json", type=Path, default=None, help="write every row and the summary here")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from prompose_grasp.perception.estimator import ProMPose
        from sim.bench_pick import _load_real_meshes

        _load_real_meshes()  # says where the meshes should be when they are not there
        estimator = ProMPose.default()
        rows = []
        seeds = _seeds(args.seeds)
        for k, seed in enumerate(seeds):
            row = fit_one(seed, estimator)
            rows.append(row)
            print(f"[{k + 1}/{len(seeds)}] " + row_line(row), flush=True)
    except PromposeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    summary = summarise(rows)
    print(
        f"\nseeds {args.seeds}: n {summary['n']}  3D50 {summary['3d50']:.0f} %  "
        f"3D75 {summary['3d75']:.0f} %  mean IoU {summary['mean_iou']:.3f}  "
        f"median IoU {summary['median_iou']:.3f}  "
        f"median centre error {summary['median_centre_error_cm']:.2f} cm  (hidden {summary['hidden']})"
    )
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
