"""Benchmark of the metric 9-DoF fit on a synthetic dataset split, against oriented-bounding-box baselines.

Run from the repository root on a dataset written by `python -m sim.dataset` (docs/sim.md):

    python -m prompose_grasp.eval.bench_fit --data DIR [--split test] [--json out.json]

Per frame and per object of the split's categories in view (the standard protocol's ground truth, at least 64
depth pixels: `eval.synthetic.evaluated_objects`), with the ground-truth instance mask (the *oracle mask*,
named so: it isolates the fit from grounding):

- points: the masked depth back-projected with the frame's intrinsics;
- support plane: the library's `perception.grounding.plane.fit_support_plane` (RANSAC) on every 4th pixel of
  the depth image (no ground truth; the table is the largest plane); the same plane for every method;
- prior: `PriorLibrary().generate(prompt, points, up)` from the object's prompt;
- ours (cold): `fit_pose(points, prior, support_plane_cam=plane, scene=SceneView(depth, intrinsics, mask))`
  (the depth image tells the fit which prior points the camera could not have seen: off the image, behind
  an occluder);
- ours (warm): `fit_pose(..., init=<this object's fit in the previous frame>)` (timing, and tracking-only
  accuracy: frame 0 cold, later frames warm only);
- baseline `obb`: `trimesh.bounds.oriented_bounds` of the [p5, p95] depth-clipped points; the OBB axis
  closest to the plane normal becomes +y (pointing up), the longer of the other two +x, z = x cross y;
- baseline `obb_plane`: the same box with its bottom extended down to the support plane (amodal height), what
  a careful user would add.

All methods are scored in the same run by `prompose_grasp.eval.compute_nocs_map` in the three IoU modes (exact
is the headline), with the dataset's y-symmetric categories and mug handle visibility from the ground truth
(the NOCS protocol: a mug whose handle is not seen counts as symmetric about y). The dataset's meta has
`handle_visible` (>= 20 pixels of the handle's own geom in a segmentation render, `sim.dataset`); for older
datasets without it, the handle is visible when >= 20 masked points lie in its part of the ground-truth box.
Library code never sees ground truth; only this script reads it.
"""

from __future__ import annotations

import argparse
import logging
import math
import platform
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.eval.baselines import obb_baseline
from prompose_grasp.eval.report import write_report_json
from prompose_grasp.eval.synthetic import evaluated_objects, nocs_image_result, nocs_tables
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.dataset import read_split, scene_frames
from prompose_grasp.perception.estimator import plane_vector
from prompose_grasp.perception.fit import FitConfig, SceneView, fit_pose
from prompose_grasp.perception.grounding.plane import fit_support_plane
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

log = logging.getLogger(__name__)

_HANDLE_MIN_PIXELS = 20


# --------------------------------------------------------------------------------------------------------
# Support plane (no ground truth)


def support_plane(depth_m: np.ndarray, intr: CameraIntrinsics) -> SupportPlane | None:
    """The library's support-plane fit (`perception.grounding.plane.fit_support_plane`, RANSAC) on every 4th
    pixel of the depth image, or None."""
    full = back_project(depth_m[::4, ::4], _subsampled(intr, 4))
    return fit_support_plane(full, GroundingConfig())


# --------------------------------------------------------------------------------------------------------
# Ground-truth-side helpers (benchmark only)


def _handle_visible(obj: dict[str, Any], points_cam: np.ndarray) -> bool:
    """True when the mug's handle is seen (dataset meta `handle_visible`, from a geom-level segmentation
    render; datasets without it: >= 20 masked points in the handle's part of the ground-truth box), True for
    non-mugs."""
    if obj["category"] != "mug":
        return True
    if "handle_visible" in obj:
        return bool(obj["handle_visible"])
    gt = Pose9D(obj["R"], obj["t"], obj["size"])
    local = gt.points_to_object(points_cam)
    params = obj.get("mesh", {}).get("params", {})
    reach = float(params.get("handle_reach_m", 0.03))
    x_max = 0.5 * float(gt.size[0])
    in_handle = local[:, 0] > x_max - 0.6 * reach
    return bool(np.count_nonzero(in_handle) >= _HANDLE_MIN_PIXELS)


# --------------------------------------------------------------------------------------------------------
# Main loop


def run(
    data: Path, split: str = "test", max_frames: int | None = None, config: FitConfig | None = None
) -> dict[str, Any]:
    from prompose_grasp.eval import nocs_box_iou, nocs_pose_error
    from prompose_grasp.perception.priors import PriorLibrary

    cfg = config or FitConfig()
    doc = read_split(data)
    categories = sorted(doc[split]["categories"])
    synsets = ["BG", *categories]
    library = PriorLibrary()
    priors: dict[str, Any] = {}
    methods = ("ours", "ours_warm_track", "obb", "obb_plane")
    per_image: dict[str, list[dict[str, Any]]] = {m: [] for m in methods}
    times: dict[str, list[float]] = defaultdict(list)
    plane_err_deg: list[float] = []
    records: list[dict[str, Any]] = []
    sym_by_cat: dict[str, str] = {}
    frames_done = 0
    t_start = time.perf_counter()
    for scene in doc[split]["scenes"]:
        # per instance: the last pose and the prior (or articulated variant) it was fitted with
        prev: dict[int, tuple[Pose9D, Any]] = {}
        track: dict[int, tuple[Pose9D, Any]] = {}
        for sf in scene_frames(data, scene):
            if max_frames is not None and frames_done >= max_frames:
                break
            depth, intr = sf.frame.depth_m, sf.frame.intrinsics
            mask = sf.ground_truth_instance_mask
            t0 = time.perf_counter()
            support = support_plane(depth, intr)
            times["plane"].append(time.perf_counter() - t0)
            plane = plane_vector(support)
            up = None if support is None else support.normal_cam
            gts: list[tuple[int, Pose9D, bool]] = []
            preds: dict[str, list[tuple[int, Pose9D]]] = {m: [] for m in methods}
            for obj in (o.meta for o in evaluated_objects(sf, categories)):
                cat = obj["category"]
                sym_by_cat[cat] = obj["symmetry"]
                cls = synsets.index(cat)
                gt = Pose9D(obj["R"], obj["t"], obj["size"])
                if up is not None:
                    plane_err_deg.append(math.degrees(math.acos(min(1.0, abs(float(gt.R[:, 1] @ up))))))
                obj_mask = mask == obj["id"]  # oracle mask
                pts = back_project(depth, intr, obj_mask)
                gts.append((cls, gt, _handle_visible(obj, pts)))
                prompt = obj["prompt"]
                t0 = time.perf_counter()
                prior = priors.get(prompt)
                if prior is None:
                    prior = library.generate(prompt, observation_points=pts, up=up)
                    priors[prompt] = prior
                times["prior"].append(time.perf_counter() - t0)
                view = SceneView(depth, intr, obj_mask)
                res = fit_pose(pts, prior, cfg, support_plane_cam=plane, scene=view)
                times["ours_cold"].append(res.time_s)
                preds["ours"].append((cls, res.pose))
                iid = int(obj["id"])
                if iid in prev:
                    p_pose, p_prior = prev[iid]
                    warm = fit_pose(pts, p_prior, cfg, support_plane_cam=plane, init=p_pose, scene=view)
                    times["ours_warm"].append(warm.time_s)
                if iid in track:
                    t_pose, t_prior = track[iid]
                    tr = fit_pose(pts, t_prior, cfg, support_plane_cam=plane, init=t_pose, scene=view)
                    track[iid] = (tr.pose, t_prior)
                else:
                    track[iid] = (res.pose, res.prior or prior)
                preds["ours_warm_track"].append((cls, track[iid][0]))
                prev[iid] = (res.pose, res.prior or prior)
                t0 = time.perf_counter()
                preds["obb"].append((cls, obb_baseline(pts, support, extend_to_plane=False)))
                times["obb"].append(time.perf_counter() - t0)
                preds["obb_plane"].append((cls, obb_baseline(pts, support)))
                ysym_obj = obj["symmetry"] == "y_continuous" or (cat == "mug" and not gts[-1][2])
                rec = {
                    "scene": scene,
                    "frame": sf.index,
                    "id": iid,
                    "category": cat,
                    "points": len(pts),
                    "handle_visible": int(gts[-1][2]),
                    "ours_size_ratio": (res.pose.size / gt.size).tolist(),
                    "ours_hypothesis": res.mode,
                }
                for m in ("ours", "obb"):
                    pred = preds[m][-1][1]
                    a, sa = pred.to_nocs_sRT()
                    b, sb = gt.to_nocs_sRT()
                    rec[f"{m}_iou"] = nocs_box_iou(a, sa, b, sb, iou_mode="exact", y_symmetric=ysym_obj)
                    rec[f"{m}_deg"], rec[f"{m}_cm"] = nocs_pose_error(a, b, y_symmetric=ysym_obj)
                records.append(rec)
            for m in methods:
                per_image[m].append(nocs_image_result(gts, [(c, p, 1.0) for c, p in preds[m]]))
            frames_done += 1
            log.info("%s frame %d: %d objects (%.1f s)", scene, sf.index, len(gts),
                     time.perf_counter() - t_start)  # fmt: skip
    ysym = tuple(c for c, s in sym_by_cat.items() if s == "y_continuous")
    tables = nocs_tables(per_image, synsets, ysym)
    n_gt = sum(len(r["gt_class_ids"]) for r in per_image["ours"])
    n_pred = sum(len(r["pred_class_ids"]) for r in per_image["ours"])
    timing = {
        k: {
            "n": len(v),
            "median_ms": 1e3 * float(np.median(v)),
            "p90_ms": 1e3 * float(np.percentile(v, 90)),
            "mean_ms": 1e3 * float(np.mean(v)),
        }
        for k, v in times.items()
        if v
    }
    return {
        "data": str(data),
        "split": split,
        "frames": frames_done,
        "gt_objects": n_gt,
        "predicted_objects": n_pred,
        "categories": categories,
        "y_symmetric_classes": list(ysym),
        "plane_error_deg": {
            "median": float(np.median(plane_err_deg)) if plane_err_deg else math.nan,
            "max": float(np.max(plane_err_deg)) if plane_err_deg else math.nan,
        },
        "tables": tables,
        "objects": records,
        "timing": timing,
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "python": sys.version,
        },
        "config": repr(cfg),
    }


def _subsampled(intr: CameraIntrinsics, k: int) -> CameraIntrinsics:
    """Intrinsics of the image subsampled by taking every k-th pixel (pixel centres at u = k u')."""
    return CameraIntrinsics(
        intr.fx / k,
        intr.fy / k,
        intr.cx / k,
        intr.cy / k,
        math.ceil(intr.width / k),
        math.ceil(intr.height / k),
    )


_COLS = ("3D25", "3D50", "3D75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")


def format_report(report: dict[str, Any]) -> str:
    plane_err = report["plane_error_deg"]
    lines = [
        f"data {report['data']} split {report['split']}: {report['frames']} frames, "
        f"{report['gt_objects']} GT objects, {report['predicted_objects']} predicted "
        f"(oracle masks); support plane error vs GT up: median {plane_err['median']:.2f} deg, "
        f"max {plane_err['max']:.2f} deg",
    ]
    for mode in ("exact", "aligned", "nocs"):
        lines.append(f"\nmean AP [%], iou_mode={mode}")
        lines.append(f"{'method':18s}" + "".join(f"{c:>10s}" for c in _COLS))
        for m, t in report["tables"].items():
            row = t[mode]["mean"]
            lines.append(f"{m:18s}" + "".join(f"{row[c]:10.1f}" for c in _COLS))
    lines.append("\nper category, iou_mode=exact")
    lines.append(f"{'method':18s}{'category':10s}" + "".join(f"{c:>10s}" for c in _COLS))
    for m, t in report["tables"].items():
        for cat, row in t["exact"]["per_class"].items():
            lines.append(f"{m:18s}{cat:10s}" + "".join(f"{row[c]:10.1f}" for c in _COLS))
    lines.append("\ntiming per object [ms]")
    for k, v in report["timing"].items():
        lines.append(f"{k:12s} n={v['n']:4d} median {v['median_ms']:7.1f}  p90 {v['p90_ms']:7.1f}  "
                     f"mean {v['mean_ms']:7.1f}")  # fmt: skip
    return "\n".join(lines)


def _field_value(key: str, text: str) -> Any:
    """`text` as the type of the FitConfig field `key` (bool: true/false/1/0; bool("false") would be True)."""
    default = getattr(FitConfig(), key, None)
    if default is None or isinstance(default, tuple):
        raise SystemExit(f"--set {key}=...: not a FitConfig field of a scalar type")
    if isinstance(default, bool):
        if text.lower() not in ("true", "false", "1", "0"):
            raise SystemExit(f"--set {key}={text}: a bool field takes true, false, 1 or 0")
        return text.lower() in ("true", "1")
    return type(default)(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m prompose_grasp.eval.bench_fit", description=__doc__)
    parser.add_argument("--data", required=True, type=Path, help="dataset folder (with split.json)")
    parser.add_argument("--split", default="test")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--json", type=Path, default=None, help="write the report here")
    parser.add_argument(
        "--set", action="append", default=[], metavar="FIELD=VALUE", help="override a FitConfig field"
    )
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    overrides = {key: _field_value(key, value) for key, _, value in (s.partition("=") for s in args.set)}
    report = run(args.data, args.split, args.max_frames, FitConfig(**overrides))
    sys.stdout.write(format_report(report) + "\n")
    if args.json is not None:
        write_report_json(report, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
