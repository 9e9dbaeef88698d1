"""Benchmark of the learned pose head against the geometric fit on a synthetic dataset split (issue: the
network's evaluation and the paper's Table 2 ablations).

    python -m prompose_grasp.eval.bench_network --data DIR --weights full=A.pt --weights no_temporal=B.pt \
        [--split test] [--max-frames N] [--no-fit] [--json out.json]

Per frame and object of the split's categories in view (the standard protocol's ground truth, at least 64
depth pixels: `eval.synthetic.evaluated_objects`), with the ground-truth instance mask (the *oracle mask*,
named so: every method sees the same points, grounding is left out), online (each frame sees only itself and
the frames before it):

- `fit`: `fit_pose(points, prior, support_plane_cam=plane)`, the embedded default (cold, every frame);
- `net:NAME`: the network of checkpoint NAME on the window of the object's last `window` frames ending at this
  frame (`NetworkPoseHead.predict`), its pose for this frame;
- `net+fit:NAME`: that pose refined by the test-time L_geo fit (`fit_pose(..., init=network pose)`).

The plane is the library's RANSAC support plane (no ground truth), priors come from the prompt
(`PriorLibrary.generate`), as in `bench_fit`. Scores: `compute_nocs_map` in the three IoU modes; mug handle
visibility and y-symmetric categories come from the dataset (NOCS protocol). Ground truth is read only here.
"""

from __future__ import annotations

import argparse
import logging
import platform
import sys
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.eval.bench_fit import support_plane
from prompose_grasp.eval.report import write_report_json
from prompose_grasp.eval.synthetic import evaluated_objects, nocs_image_result, nocs_tables
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.dataset import read_split, scene_frames
from prompose_grasp.perception.estimator import plane_vector
from prompose_grasp.perception.fit import fit_pose
from prompose_grasp.perception.network.pose_head import MaskedFrame, NetworkPoseHead, PreparedFrame

log = logging.getLogger(__name__)

_COLS = ("3D25", "3D50", "3D75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")
_MODES = ("exact", "aligned", "nocs")


def run(
    data: str | Path,
    checkpoints: Mapping[str, str | Path],
    split: str = "test",
    max_frames: int | None = None,
    with_fit: bool = True,
    refine: Sequence[str] | None = None,
) -> dict[str, Any]:
    """The report dict (tables per method and IoU mode, timings, what was run).

    `refine` names the checkpoints that also get a `net+fit` row (default: all of them).
    """
    from prompose_grasp.perception.priors import PriorLibrary
    from prompose_grasp.perception.text import default_text_encoder

    if not checkpoints:
        raise InvalidInputError("give at least one checkpoint (--weights NAME=PATH)")
    doc = read_split(data)
    categories = sorted(doc[split]["categories"])
    synsets = ["BG", *categories]
    encoder = default_text_encoder("cpu")
    library = PriorLibrary(encoder=encoder)
    heads = {name: NetworkPoseHead.load(path, encoder) for name, path in checkpoints.items()}
    methods = [*(["fit"] if with_fit else []), *(f"net:{n}" for n in heads)]
    refined = set(heads) if refine is None else set(refine)
    if refined - set(heads):
        raise InvalidInputError(f"--refine names unknown checkpoints {sorted(refined - set(heads))}")
    methods += [f"net+fit:{n}" for n in heads if n in refined] if with_fit else []
    per_image: dict[str, list[dict[str, Any]]] = {m: [] for m in methods}
    times: dict[str, list[float]] = defaultdict(list)
    sym_by_cat: dict[str, str] = {}
    priors: dict[str, Any] = {}
    frames_done = 0
    t_start = time.perf_counter()
    for scene in doc[split]["scenes"]:
        # per (checkpoint, instance): the prepared frames so far (preprocessing depends on the config)
        history: dict[tuple[str, int], list[PreparedFrame | None]] = defaultdict(list)
        for sf in scene_frames(data, scene):
            if max_frames is not None and frames_done >= max_frames:
                break
            frame = sf.frame
            support = support_plane(frame.depth_m, frame.intrinsics)
            plane = plane_vector(support)
            up = None if support is None else support.normal_cam
            gts: list[tuple[int, Pose9D, bool]] = []
            preds: dict[str, list[tuple[int, Pose9D]]] = {m: [] for m in methods}
            for obj in evaluated_objects(sf, categories):
                sym_by_cat[obj.category] = obj.symmetry
                cls = synsets.index(obj.category)
                gts.append((cls, obj.pose, obj.handle_visible))
                mask = sf.ground_truth_instance_mask == obj.instance_id  # oracle mask
                pts = back_project(frame.depth_m, frame.intrinsics, mask)
                masked = MaskedFrame(frame.rgb, frame.depth_m, frame.intrinsics, mask)
                prior = priors.get(obj.prompt)
                if prior is None:
                    prior = priors[obj.prompt] = library.generate(obj.prompt, observation_points=pts, up=up)
                if with_fit:
                    res = fit_pose(pts, prior, support_plane_cam=plane)
                    times["fit"].append(res.time_s)
                    preds["fit"].append((cls, res.pose))
                for name, head in heads.items():
                    t0 = time.perf_counter()
                    seen = history[(name, obj.instance_id)]
                    seen.append(head.prepare(masked))
                    pose = head.predict(seen, obj.prompt, prior.points)[-1]
                    times[f"net:{name}"].append(time.perf_counter() - t0)
                    if pose is None:  # cannot happen with a ground truth's >= 64 points; kept as a miss
                        continue
                    preds[f"net:{name}"].append((cls, pose))
                    if with_fit and name in refined:
                        refined_fit = fit_pose(pts, prior, support_plane_cam=plane, init=pose)
                        times[f"net+fit:{name}"].append(time.perf_counter() - t0)
                        preds[f"net+fit:{name}"].append((cls, refined_fit.pose))
            for m in methods:
                per_image[m].append(nocs_image_result(gts, [(c, p, 1.0) for c, p in preds[m]]))
            frames_done += 1
            elapsed = time.perf_counter() - t_start
            log.info("%s frame %d: %d objects (%.0f s)", scene, sf.index, len(gts), elapsed)
    ysym = tuple(c for c, s in sym_by_cat.items() if s == "y_continuous")
    tables = nocs_tables(per_image, synsets, ysym)
    timing = {
        k: {"n": len(v), "median_ms": 1e3 * float(np.median(v)), "mean_ms": 1e3 * float(np.mean(v))}
        for k, v in times.items()
        if v
    }
    return {
        "data": str(data),
        "split": split,
        "frames": frames_done,
        "gt_objects": sum(len(r["gt_class_ids"]) for r in next(iter(per_image.values()))),
        "categories": categories,
        "checkpoints": {k: str(v) for k, v in checkpoints.items()},
        "tables": tables,
        "timing": timing,
        "machine": {"platform": platform.platform(), "python": sys.version},
    }


def format_report(report: dict[str, Any]) -> str:
    lines = [
        f"data {report['data']} split {report['split']}: {report['frames']} frames, "
        f"{report['gt_objects']} GT objects (oracle masks)"
    ]
    width = max(len(m) for m in report["tables"]) + 2
    for mode in _MODES:
        lines.append(f"\nmean AP [%], iou_mode={mode}")
        lines.append(f"{'method':{width}s}" + "".join(f"{c:>10s}" for c in _COLS))
        for m, t in report["tables"].items():
            lines.append(f"{m:{width}s}" + "".join(f"{t[mode]['mean'][c]:10.1f}" for c in _COLS))
    lines.append("\nper category, iou_mode=exact")
    for m, t in report["tables"].items():
        for cat, row in t["exact"]["per_class"].items():
            lines.append(f"{m:{width}s}{cat:10s}" + "".join(f"{row[c]:10.1f}" for c in _COLS))
    lines.append("\ntime per object [ms] (net+fit includes the network)")
    for k, v in report["timing"].items():
        lines.append(f"{k:{width}s} n={v['n']:4d} median {v['median_ms']:7.1f}  mean {v['mean_ms']:7.1f}")
    return "\n".join(lines)


def _checkpoint_arg(text: str) -> tuple[str, str]:
    name, sep, path = text.partition("=")
    if not sep:
        name, path = Path(text).stem, text
    return name, path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m prompose_grasp.eval.bench_network", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--data", required=True, type=Path, help="dataset folder (with split.json)")
    parser.add_argument(
        "--weights", action="append", required=True, metavar="NAME=PATH", help="a checkpoint (repeatable)"
    )
    parser.add_argument("--split", default="test")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--no-fit", action="store_true", help="only the network rows (faster)")
    parser.add_argument(
        "--refine", action="append", default=None, metavar="NAME", help="net+fit rows only for these"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the report here")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    checkpoints = dict(_checkpoint_arg(w) for w in args.weights)
    report = run(args.data, checkpoints, args.split, args.max_frames, not args.no_fit, args.refine)
    sys.stdout.write(format_report(report) + "\n")
    if args.json is not None:
        write_report_json(report, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
